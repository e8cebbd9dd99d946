"""The HTTP API, one router per resource: health and source, frames, measurements, recordings, checks, options."""
