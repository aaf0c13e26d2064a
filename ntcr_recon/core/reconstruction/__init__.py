"""The stages over the layers below and the frame loop: the Relocator (the relocation's steps in order,
relocation_steps), edge bands, meshing, still-frame selection, and the Reconstructor (the offline frame loop)."""
