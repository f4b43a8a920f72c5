"""The experiments' commands say at the door that they need a checkout's committed results, before anything
is read or written, where the working directory holds none."""

import pytest

from jaxsocial.experiments import __main__ as cli
from jaxsocial.experiments import branch_design, evaluation_design, followup, sweep, takeoff_power

COMMANDS = {
    "experiments": (cli.main, ["list"]),
    "sweep": (sweep.main, ["list"]),
    "pooled": (takeoff_power.main, []),
    "evaluation_design": (evaluation_design.main, ["power", "transfer"]),
    "branch_design": (branch_design.main, ["power", "mixing"]),
    "followup": (followup.main, ["figure", "h1_laptop"]),
}


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_a_command_outside_a_checkout_says_it_needs_one(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    main, argv = COMMANDS[name]
    with pytest.raises(SystemExit, match=r"no benchmarks/results/ in .*run them from the root of a clone"):
        main(argv)
    assert not any(tmp_path.iterdir())  # nothing written
