"""The training run: its config (`config`), its validated static part (`startup`), the compiled program
(`loop`), the driver's steps between chunks and the loop over them (`driver`), the stages (`schedule`), the
run directory (`rundir`, `runlock`, `logs`, `metrics`, `checkpoint`), branching from another run
(`init_from`), devices (`distributed`), the machine's choice of kernels and dtype (`autotune`), the compile
cache and the non-finite checks."""
