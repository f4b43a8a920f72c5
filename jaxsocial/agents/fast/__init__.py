"""How the network runs fast on CPUs, not what it computes: the conv kernels (`conv`: Winograd, im2col, XLA),
the conv layers in chunks of frames with only their activations saved (`chunks`), matrix products with
bfloat16 inputs (`precision`), and the machine's own choice among them (`autotune`). The Flax modules
(`jaxsocial.agents.modules`) select them through `NetworkConfig.conv_impl`, `chunk` and `dtype`."""
