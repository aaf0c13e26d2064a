"""The relocation's steps: centreline, alignment, outline, notches, tip, and moving points onto the reference."""
