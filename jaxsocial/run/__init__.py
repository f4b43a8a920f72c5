"""The training run: its config (`config`), its validated static part (`startup`), the compiled program
(`loop`), the driver's steps between chunks and the loop over them (`driver`), the stages (`schedule`), the
run directory (`rundir`, its one owner; `runlock`, `metrics`, `checkpoint`; JSON files: `jsonio`),
branching from another run (`init_from`), devices (`distributed`), the machine's choice of kernels and dtype
(`autotune`), the compile cache, the non-finite checks, and what a run records of the code and machine it
ran on (`checkout`: the commit and whether the package's files were its; `provenance`: the process file)."""
