"""Files the device layer writes and reads: depthruler's recording format and the MCAP export."""
