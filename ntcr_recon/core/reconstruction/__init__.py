"""The frame loop over the layers below: the Reconstructor, still-frame selection, meshing."""
