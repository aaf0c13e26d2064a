"""Foundations every layer uses: compiled kernels, rigid transforms, robust statistics, the configuration schema's
machinery."""
