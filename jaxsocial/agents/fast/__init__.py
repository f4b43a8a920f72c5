"""How the network runs fast on CPUs, not what it computes: the conv kernels (`conv`: Winograd, im2col, XLA),
the conv layers in batches of frames with only their activations saved (`frame_batches`) and matrix products
with bfloat16 inputs (`precision`). The Flax modules (`jaxsocial.agents.modules`) select them through
`NetworkConfig.conv_impl`, `frame_batch` and `dtype`; the run's `jaxsocial.run.autotune` lets the machine
choose."""
