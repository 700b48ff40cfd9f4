"""Floor 4, the networks: heterogeneous graphs built from observations (:mod:`.graph`), the attention
kernels (:mod:`.attention`) and DA-HGNN and NCM with their weight files (:mod:`.dahgnn`).

Imports the floors below and the shared leaves; PyTorch is imported lazily, where a network is built.
"""
