"""How a learner's batch is split over devices inside a jitted function: the `Devices` interface the PPO
update and the rollout take (`dp`), and `ONE_DEVICE`, the default. `jaxsocial.run.distributed.DataParallel`
is the many-device one: it splits the rollout's environments and each minibatch's segments over a mesh, and
the losses' means and the gradient stay those of the whole batch."""

from collections.abc import Callable
from typing import Any, Protocol


class Devices(Protocol):
    """How a batch is split over devices inside a jitted function (pytree prefixes of batch axes, None:
    replicated): `shard` constrains a tree's layout, `per_device(fn, in_axes, out_axes)` runs `fn` on each
    device's share, `axis_name` names the devices' axis inside it (None on one device)."""

    axis_name: str | None

    def shard(self, tree: Any, axes: Any) -> Any: ...

    def per_device(self, fn: Callable, in_axes: Any, out_axes: Any) -> Callable: ...


class OneDevice:
    """`Devices` of a batch on one device: nothing to split, every function runs on the whole batch."""

    axis_name = None

    def shard(self, tree: Any, axes: Any) -> Any:
        return tree

    def per_device(self, fn: Callable, in_axes: Any, out_axes: Any) -> Callable:
        return fn


ONE_DEVICE = OneDevice()
