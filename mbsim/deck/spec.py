"""The validated deck: plain data produced by :func:`mbsim.deck.load_deck`.

Everything here is already checked (types, shapes, units converted to SI,
parameters substituted).  Each item carries ``where`` so that later stages
(`compile_model`, the analyses) can still point at the deck line that made it.
Vectors are float numpy arrays; nothing here is indexed by body number yet:
names become indices only in :func:`mbsim.model.compile_model`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mbsim.errors import Where


@dataclass
class FunctionSpec:
    """A scalar function of time (drivers, time-varying loads).

    kind: 'constant' | 'expression' | 'polynomial' | 'table' | 'harmonic'
      constant   data = {'value': float}
      expression data = {'expr': Expression}          (variable t, parameters already bound)
      polynomial data = {'coefficients': [c0, c1, ...]}   f = c0 + c1 t + c2 t^2 + ...
      table      data = {'t': array, 'value': array, 'interpolation': 'cubic'|'linear'|'akima'}
      harmonic   data = {'amplitude', 'frequency' (rad/s), 'phase' (rad), 'offset'}
    """

    kind: str
    data: dict[str, Any]
    where: Where = field(default_factory=Where)


@dataclass
class ShapeSpec:
    """One piece of a body's drawn shape (mbsim.deck.shapes; docs/deck.md#shapes).

    kind: 'box' | 'cylinder' | 'sphere' | 'capsule' | 'mesh'; data: its dimensions in SI
    ('size' (3,), 'radius', 'length', 'axis' 'x'|'y'|'z'; a mesh's 'vertices' (nv, 3) in the
    file's units, 'faces' (nf, 3) int and 'scale'); offset: (3,) centre in the body frame, m.
    """

    kind: str
    data: dict[str, Any]
    offset: np.ndarray
    color: str = ""  # '#rrggbb', '' for the viewer's choice
    where: Where = field(default_factory=Where)


@dataclass
class BodySpec:
    name: str
    mass: float
    inertia: np.ndarray  # (3, 3) J' about the centroid, body frame
    r: np.ndarray  # (3,) centroid, global, initial estimate
    p: np.ndarray  # (4,) Euler parameters (e0, e1, e2, e3), normalised on load
    rdot: np.ndarray | None  # (3,) centroid velocity, global (None: not given, free)
    omega: np.ndarray | None  # (3,) angular velocity, global frame (None: not given)
    omega_local: np.ndarray | None  # (3,) angular velocity, body frame (None: not given)
    ground: bool = False  # True: the ground body, fixed by a 6-equation ground constraint
    where: Where = field(default_factory=Where)
    shapes: list[ShapeSpec] | None = None  # `shape:` (None: derived from joints and inertia)


@dataclass
class PointSet:
    """The P, Q, R rows of one body in a joint table (body coordinates). Q, R may be None."""

    P: np.ndarray
    Q: np.ndarray | None = None
    R: np.ndarray | None = None
    where: Where = field(default_factory=Where)


@dataclass
class JointSpec:
    """A joint or a constraint. ``bodies`` = (i, j); one-body constraints have j None.

    ``points`` maps body name -> PointSet.  ``data`` holds type data, e.g.
    {'distance': 0.10922} for 'distance'/'revolute-spherical'/'spherical-spherical',
    {'axis': 'x'|'y'|'z', 'value': FunctionSpec} for 'absolute'.
    """

    name: str
    type: str
    bodies: tuple[str, str | None]
    points: dict[str, PointSet]
    data: dict[str, Any] = field(default_factory=dict)
    where: Where = field(default_factory=Where)


@dataclass
class DriverSpec:
    """A driving constraint: type 'rotation' | 'translation' | 'distance' | 'absolute'.

    rotation/translation: ``joint`` names a revolute/cylindrical/translational joint whose
    frames define the axis and the reference directions.
    distance: ``bodies`` and ``points`` (P on each body).
    absolute: ``bodies`` = (body, None), ``points`` = {body: PointSet(P)}, data['axis'] in x|y|z.
    """

    name: str
    type: str
    function: FunctionSpec
    joint: str | None = None
    bodies: tuple[str, str | None] | None = None
    points: dict[str, PointSet] = field(default_factory=dict)
    data: dict[str, Any] = field(default_factory=dict)
    where: Where = field(default_factory=Where)


@dataclass
class ForceSpec:
    """A force element. ``data`` holds the type's fields, numbers already in SI, laws as
    FunctionSpec or Expression objects (see docs/deck.md for each type's fields)."""

    name: str
    type: str
    bodies: tuple[str, ...]
    points: dict[str, PointSet] = field(default_factory=dict)
    data: dict[str, Any] = field(default_factory=dict)
    where: Where = field(default_factory=Where)


@dataclass
class OutputSpec:
    """A named point of interest: position/velocity/acceleration of a body point."""

    name: str
    body: str
    point: np.ndarray
    where: Where = field(default_factory=Where)


@dataclass
class DeckSpec:
    title: str
    file: str
    text: str  # the deck's YAML text, stored in results
    gravity: np.ndarray  # (3,) m/s^2
    parameters: dict[str, float]
    bodies: dict[str, BodySpec]
    joints: dict[str, JointSpec]
    drivers: dict[str, DriverSpec]
    forces: dict[str, ForceSpec]
    outputs: dict[str, OutputSpec]
    analysis: dict[str, dict[str, Any]]  # per-mode settings, e.g. {'kinematic': {'t_end': 1}}
    raw: dict[str, Any] = field(default_factory=dict)  # the YAML tree after overrides
    warnings: list[str] = field(default_factory=list)  # 'file:line: key.path: message'
    scene: str | None = None  # the scene applied, if any
    # studies: name -> {'description': str, 'cases': [case], 'figures': [figure],
    # 'numbers': [number]}, plain validated data read by mbsim.study (docs/studies.md)
    studies: dict[str, dict[str, Any]] = field(default_factory=dict)
    # outputs: measures (name -> mbsim.measures.OutputMeasure) and `only` (channel patterns
    # restricting what a run computes and writes; None: everything), docs/deck.md#outputs
    output_measures: dict[str, Any] = field(default_factory=dict)
    output_only: tuple[str, ...] | None = None
    # events: name -> mbsim.events.EventSpec (conditions located during a dynamic run)
    events: dict[str, Any] = field(default_factory=dict)
