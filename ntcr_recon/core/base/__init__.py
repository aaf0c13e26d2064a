"""Foundations every layer uses: compiled kernels, rigid transforms, the configuration schema's machinery."""
