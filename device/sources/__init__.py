"""Source kinds of the device layer: cameras (OAK, V4L2 pairs), stereo video, datasets and bags."""
