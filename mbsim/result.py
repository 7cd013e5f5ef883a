"""The one Result type that every analysis returns and the HDF5 writer stores.

A result is a time axis plus named *channels*.  A channel name is a slash path,
``bodies/crank/r``, ``drivers/crank/torque``, ``joints/REV1/force``, and its data has the
time axis first: shape (nt,) or (nt, k).  On the command line the same name may be written
with dots (``drivers.crank.torque``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

STATUS_COMPLETE = "complete"
STATUS_INCOMPLETE = "incomplete"  # stopped part-way: data up to the failure, message says why


@dataclass
class Channel:
    data: np.ndarray  # (nt,) or (nt, k); first axis is time
    unit: str = ""  # SI unit, e.g. 'm', 'N m', 'rad/s'
    description: str = ""
    components: tuple[str, ...] = ()  # labels of the second axis, e.g. ('x', 'y', 'z')


@dataclass
class Result:
    mode: str  # 'kinematic' | 'equilibrium' | 'inverse' | 'dynamic' | 'assembly'
    t: np.ndarray  # (nt,) output times, s
    channels: dict[str, Channel] = field(default_factory=dict)
    status: str = STATUS_COMPLETE
    message: str = ""
    settings: dict[str, Any] = field(default_factory=dict)  # options the analysis ran with
    counters: dict[str, int | float] = field(default_factory=dict)  # steps, evaluations, ...
    summary: dict[str, Any] = field(default_factory=dict)  # scalar findings (DOF, eigenvalues, ...)
    deck_file: str = ""
    deck_text: str = ""
    wall_time: float = 0.0
    names: dict[str, list[str]] = field(default_factory=dict)  # 'bodies', 'joints', 'drivers', ...
    # arrays without a time axis (e.g. 'linear/eigenvalues', complex): name -> (data, attrs)
    arrays: dict[str, tuple[np.ndarray, dict]] = field(default_factory=dict)
    attrs: dict[str, Any] = field(default_factory=dict)  # extra root attributes ('stable', ...)

    @property
    def complete(self) -> bool:
        return self.status == STATUS_COMPLETE

    def add(self, name: str, data, unit: str = "", description: str = "", components=()):
        self.channels[name] = Channel(np.asarray(data, dtype=float), unit, description,
                                      tuple(components))

    def channel(self, name: str) -> Channel:
        key = name.replace(".", "/")
        if key not in self.channels:
            from difflib import get_close_matches

            hint = get_close_matches(key, list(self.channels), n=3)
            msg = f"no channel {name!r}"
            if hint:
                msg += "; did you mean " + ", ".join(h.replace("/", ".") for h in hint) + "?"
            raise KeyError(msg)
        return self.channels[key]
