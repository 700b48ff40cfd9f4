"""Floor 4, the networks: heterogeneous graphs built from observations (:mod:`.graph`, their neighbour
lists :mod:`.neighbours`), the fused CPU kernels (:mod:`.kernels`, :mod:`.self_attention`,
:mod:`.cross_attention`, :mod:`.affinity`), the DA-HGNN / NCM network (:mod:`.network_config`,
:mod:`.blocks`, :mod:`.rounds`, :mod:`.network`), its policy files (:mod:`.weights`) and the policy that
acts with it (:mod:`.dahgnn`).

Imports the floors below and the shared leaves; PyTorch is imported lazily, where a network is built.
"""
