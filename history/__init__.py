"""The measurement history the service keeps: the SQLite database, the saved frame files beside it
and the log of board checks. The one owner of these formats; the service writes them, the batch
and the check read them (read-only where they do not own the write)."""
