"""How the network runs fast on CPUs, not what it computes: the conv kernels (`conv`: Winograd, im2col, XLA),
the conv layers in batches of frames with only their activations saved (`frame_batches`), matrix products with
bfloat16 inputs (`precision`), and the machine's own choice among them (`autotune`). The Flax modules
(`jaxsocial.agents.modules`) select them through `NetworkConfig.conv_impl`, `frame_batch` and `dtype`."""
