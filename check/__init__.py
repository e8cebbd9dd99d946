"""The board check (`depthruler check`): how accurate lengths from a source are, here and today,
against a printed ChArUco board of known size."""
