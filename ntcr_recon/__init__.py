"""ntcr_recon: 3-D morphology of notched tubular continuum robots from two opposed D405 cameras."""

__version__ = "0.1.0"
