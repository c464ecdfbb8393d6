"""The product's faces: the ``sage`` command line and the live dashboard server."""
