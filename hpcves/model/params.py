"""Parameters of one case: typed, frozen, validated on construction.

Three groups, one per concern:

* :class:`Physics`  -- the model of SPEC section 1 (dimensionless), published defaults;
* :class:`Numerics` -- resolution, time step and the stabilisation constants;
* :class:`RunControl` -- end time, sampling, snapshot and checkpoint intervals,
  divergence bounds.

:class:`Case` bundles them. Every check raises :class:`ConfigError` with a
message that names the offending key, so the command line can print it as is.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Literal

from hpcves.errors import ConfigError  # noqa: F401 -- where the model's users import it from
from hpcves.model import bending

#: Perimeter of the 1/2 : 1/3 ellipse, the published reference shape.
REFERENCE_LENGTH = 2.6442
#: Delta = L / R - 2 pi of the publication's 1/2 : 1/3 ellipse (geometry.excess_length_of_ellipse(2/3),
#: checked in tests/test_geometry.py); the default. The rounded 0.194, a shape of its own (still
#: accepted), settles a homogeneous vesicle 6.5e-5 rad lower (VALIDATION.md, section 1)
REFERENCE_EXCESS_LENGTH = 0.19385328260599

#: More time steps than this for one case is surely a mistake (at the fastest step measured,
#: 0.25 ms at N = 32, it is three days of one core; the published runs took 10^6 to 10^7).
MAX_STEPS = 10**9

PSI_COORDINATES = ("arclength", "ellipse_parameter")
INITIAL_SHAPES = ("ellipse", "smoothed", "stored")
INITIAL_PHASES = ("published", "domains", "random")
#: Beyond this excess length the smoothed start (geometry.smoothed_ellipse) crosses itself: its flanks
#: touch at Delta = 7.7708 (bisection, tests/test_geometry.py).
SMOOTHED_MAX_EXCESS_LENGTH = 7.77


@dataclass(frozen=True)
class ParameterName:
    """How tables and figures name a sweepable parameter: ``text`` in tables and files, ``symbol``
    (matplotlib mathtext) in figure titles, ``axis`` on a figure's axis."""

    text: str
    symbol: str
    axis: str
    long_name: str            # the netCDF/CF ``long_name`` of the (dimensionless) parameter


#: the one table of the sweepable parameters' names
PARAMETER_NAMES = {
    "shear_rate": ParameterName("S", "S", "shear rate $S$", "dimensionless shear rate S"),
    "psi_bar": ParameterName("psi_bar", r"$\bar\psi$", r"mean composition $\bar\psi$",
                             "mean soft-phase concentration psi_bar"),
    "excess_length": ParameterName("Delta", r"$\Delta$", r"excess length $\Delta$",
                                   "excess length Delta = L / R - 2 pi, R = sqrt(A / pi)"),
    "B2": ParameterName("B2", r"$B_2$", r"bending rigidity $B_2$",
                        "bending rigidity B2 of the soft phase (the hard phase's B1 = 1)"),
    "viscosity_ratio": ParameterName("lambda", r"$\lambda$", r"viscosity ratio $\lambda$",
                                     "viscosity ratio lambda of the inner to the outer fluid"),
}
#: the symbol of each sweepable parameter in tables
LABELS = {key: name.text for key, name in PARAMETER_NAMES.items()}

def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ConfigError(message)


#: the physics parameters a campaign may vary from case to case ([sweep]), in the order of a
#: case's row (campaign/study.py, run/verdict.py, reports/)
SWEEPABLE = ("shear_rate", "psi_bar", "excess_length", "B2", "viscosity_ratio")
#: sweepable parameters added after files and tables had been written, with the value every case of
#: those ran with (a row or a file without the parameter reads as that)
ADDED_LATER = {"viscosity_ratio": 1.0}


def parameter_of(values, key: str, prefix: str = "") -> float:
    """``values[prefix + key]`` -- of a case's row, or with ``prefix`` "physics." of its file's attributes --
    or the value a case written before the parameter existed ran with (:data:`ADDED_LATER`)."""
    name = prefix + key
    return values[name] if name in values else ADDED_LATER[key]


@dataclass(frozen=True)
class Physics:
    """The dimensionless model (SPEC section 1).

    ``psi_bar`` is the mean soft-phase fraction; ``psi_bar`` of exactly 0 or 1
    is a homogeneous vesicle (B = B1 or B2) whose phase field is not evolved.
    ``psi_init_coordinate`` says what alpha means in the initial phase
    psi(alpha, 0) = psi_bar + delta (3 cos 2 pi a + 0.5 cos 6 pi a + 0.5 cos 8 pi a):
    ``"arclength"`` -- the normalised arclength of the node (the published formula;
    the mean of psi is then exactly psi_bar); ``"ellipse_parameter"`` -- the
    parameter t/(2 pi) of the ellipse x = a cos t, y = b sin t at the node (what
    the authors' code does; the mean then differs from psi_bar by O(delta e^2)).
    ``initial_shape`` is the start: ``"ellipse"`` (the default), the ellipse of perimeter
    ``length`` and excess length ``excess_length`` as the publication states it; ``"smoothed"``,
    that ellipse with its tangent angle cut to the modes |k| <= 4 and rescaled to the ellipse's
    area, as the authors' code starts (geometry.smoothed_ellipse; the same length, area and
    excess length, blunter tips: curvature 8.1 instead of 26.0 at Delta = 2.3). alpha of the
    initial phase is then still that of the ellipse's nodes. ``"stored"``: the shape and phase of
    another case's stored state -- case ``stored_case`` of the campaign file ``stored_file`` (or the
    single-run file, ``stored_case`` empty) at the snapshot nearest ``stored_time``, or at its last
    state (its newest checkpoint: the end of a finished case) with ``stored_time`` = -1 -- carried
    over to this case's N, excess length and psi_bar (continuation.carried_start); the initial phase
    options are then not used.
    ``initial_phase`` is the pattern psi starts from (phasefield.py): ``"published"`` (above);
    ``"domains"``, psi_bar + delta cos(2 pi m (alpha - a0)) with m = ``phase_domains`` and a0 =
    ``phase_center``: m soft domains, the first centred at a0; ``"random"``, random amplitudes of the
    modes 1 to 8 drawn from ``phase_seed``, bounded like the published pattern by 4 delta.
    ``bending_law`` is B(psi) (bending.py): ``"linear"``, B1 + (B2 - B1) psi for
    every psi (SPEC section 1), which vanishes at psi = B1 / (B1 - B2) and lets a
    sharp tip draw the soft phase past 1 (Delta = 2.3); ``"saturating"`` (the
    default), the same on [0, 1] with B' fading to zero over ``bending_width``
    outside it, so that B stays positive (docs/numerics.md, "Bending law").
    ``viscosity_ratio`` is lambda = eta_in / eta_out (1: the publication's equal viscosities); other
    values add the double layer to the membrane's flow (flow.py; docs/numerics.md, "Viscosity
    contrast").
    """

    shear_rate: float = 10.0
    psi_bar: float = 0.3
    excess_length: float = REFERENCE_EXCESS_LENGTH
    length: float = REFERENCE_LENGTH
    B1: float = 1.0
    B2: float = 0.1
    a0: float = 100.0
    epsilon: float = 0.04
    delta: float = 0.05
    mobility: float = 1.0
    psi_init_coordinate: Literal["arclength", "ellipse_parameter"] = "arclength"
    initial_shape: Literal["ellipse", "smoothed", "stored"] = "ellipse"
    stored_file: str = ""
    stored_case: str = ""
    stored_time: float = -1.0
    initial_phase: Literal["published", "domains", "random"] = "published"
    phase_domains: int = 1
    phase_center: float = 0.0
    phase_seed: int = 0
    bending_law: Literal["linear", "saturating"] = "saturating"
    bending_width: float = 0.05
    viscosity_ratio: float = 1.0

    def __post_init__(self) -> None:
        _finite(self)
        _require(self.viscosity_ratio > 0, f"physics.viscosity_ratio = {self.viscosity_ratio}: the inner over "
                                           "the outer viscosity must be > 0")
        _require(self.shear_rate >= 0, f"physics.shear_rate = {self.shear_rate}: must be >= 0")
        _require(self.shear_rate <= MAX_SHEAR_RATE,
                 f"physics.shear_rate = {self.shear_rate:g}: at most {MAX_SHEAR_RATE:g} (bending, the unit of the "
                 "model, would be below 1e-6 of the shear's stress)")
        _require(0.0 <= self.psi_bar <= 1.0, f"physics.psi_bar = {self.psi_bar}: must lie in [0, 1]")
        _require(self.length > 0, f"physics.length = {self.length}: must be > 0")
        _require(
            self.excess_length >= 0,
            f"physics.excess_length = {self.excess_length}: no ellipse reaches a negative "
            "excess length (the circle has 0)",
        )
        _require(
            self.excess_length <= 20,
            f"physics.excess_length = {self.excess_length}: the ellipse with this excess length "
            "has an aspect ratio beyond 1:1000; not supported",
        )
        _require(self.B1 > 0, f"physics.B1 = {self.B1}: bending stiffness must be > 0")
        _require(self.B2 > 0, f"physics.B2 = {self.B2}: bending stiffness must be > 0")
        _require(self.a0 >= 0, f"physics.a0 = {self.a0}: line-energy strength must be >= 0")
        _require(self.epsilon > 0, f"physics.epsilon = {self.epsilon}: must be > 0")
        _require(self.delta >= 0, f"physics.delta = {self.delta}: must be >= 0")
        _require(self.mobility > 0, f"physics.mobility = {self.mobility}: must be > 0")
        _require(
            self.psi_init_coordinate in PSI_COORDINATES,
            f"physics.psi_init_coordinate = {self.psi_init_coordinate!r}: must be one of "
            + ", ".join(repr(c) for c in PSI_COORDINATES),
        )
        _require(self.initial_shape in INITIAL_SHAPES, f"physics.initial_shape = {self.initial_shape!r}: must be "
                 "one of " + ", ".join(repr(c) for c in INITIAL_SHAPES))
        _require(self.initial_shape != "smoothed" or self.excess_length <= SMOOTHED_MAX_EXCESS_LENGTH,
                 f"physics.excess_length = {self.excess_length}: the smoothed start crosses itself beyond "
                 f"{SMOOTHED_MAX_EXCESS_LENGTH}; use physics.initial_shape = \"ellipse\"")
        _require(self.initial_shape != "stored" or bool(self.stored_file),
                 "physics.initial_shape = \"stored\" needs physics.stored_file: the file of the state to start from")
        _require(self.stored_time == -1.0 or self.stored_time >= 0,
                 f"physics.stored_time = {self.stored_time}: a time >= 0, or -1 for the last stored state")
        _require(self.initial_phase in INITIAL_PHASES, f"physics.initial_phase = {self.initial_phase!r}: must be "
                 "one of " + ", ".join(repr(c) for c in INITIAL_PHASES))
        _require(isinstance(self.phase_domains, int) and 1 <= self.phase_domains <= 16,
                 f"physics.phase_domains = {self.phase_domains!r}: must be an integer from 1 to 16")
        _require(0.0 <= self.phase_center < 1.0, f"physics.phase_center = {self.phase_center}: must lie in [0, 1)")
        _require(isinstance(self.phase_seed, int) and self.phase_seed >= 0,
                 f"physics.phase_seed = {self.phase_seed!r}: must be an integer >= 0")
        _require(self.bending_law in bending.LAWS, f"physics.bending_law = {self.bending_law!r}: must be one of "
                 + ", ".join(repr(c) for c in bending.LAWS))
        _require(self.bending_width > 0, f"physics.bending_width = {self.bending_width}: must be > 0")
        if self.bending_law == "saturating" and \
                bending.stiffness_bounds(self.B1, self.B2, self.bending_law, self.bending_width)[0] <= 0:
            raise ConfigError(f"physics.bending_width = {self.bending_width}: the saturating law would reach "
                              "B <= 0 outside [0, 1]; it needs bending_width < "
                              f"{bending.largest_width(self.B1, self.B2):.3g}")

    @property
    def phase_spread(self) -> float:
        """The largest |psi - psi_bar| the initial phase can have: delta for ``"domains"``, 4 delta otherwise."""
        return self.delta if self.initial_phase == "domains" else 4.0 * self.delta

    @property
    def contrast(self) -> bool:
        """True where the inner and outer viscosities differ (viscosity_ratio != 1)."""
        return self.viscosity_ratio != 1.0

    @property
    def homogeneous(self) -> bool:
        """True for psi_bar = 0 or 1: one lipid phase, no phase-field dynamics."""
        return self.psi_bar in (0.0, 1.0)

    def bending(self, psi):
        """B(psi) = B1 + (B2 - B1) s(psi): s = psi for the linear law, and on [0, 1] for both (bending.py)."""
        return self.B1 + (self.B2 - self.B1) * bending.fraction(psi, self.bending_law, self.bending_width)

    def bending_prime(self, psi):
        """B'(psi) = (B2 - B1) s'(psi): a scalar where it is the constant B2 - B1, else an array."""
        return (self.B2 - self.B1) * bending.fraction_prime(psi, self.bending_law, self.bending_width)

    def bending_second(self, psi):
        """B''(psi) = (B2 - B1) s''(psi), or None where it is 0 (the linear law, psi inside [0, 1])."""
        second = bending.fraction_second(psi, self.bending_law, self.bending_width)
        return None if second is None else (self.B2 - self.B1) * second


@dataclass(frozen=True)
class Numerics:
    """Discretisation.

    ``N`` material points, equispaced in arclength (even, >= 16). With ``N_max``
    > N, N adapts during the run between N and N_max (numerics.N = "auto" in a
    file; run/resolution.py): it grows when the spectral tail of theta_tilde or
    psi passes ``resize_tail`` and shrinks when the tail on a smaller grid has
    stayed below resize_tail / 10 for ``shrink_after`` shear times. ``dt`` the time
    step of a fixed-step run. ``rtol`` (with ``atol``) makes the step adaptive
    instead: variable-step SBDF2 under error control (stepcontrol.py), steps
    up to ``dt_max``, the first one ``dt_initial``; ``dt`` is then not used.
    ``bending_stabilization`` multiplies max(B1, B2) in the implicit part
    c |k|^3 / 4 of the tangent-angle equation (>= 1 keeps SBDF2 stable for every
    local B). ``phase_stabilization`` is the constant s of the linear
    stabilisation (a0/eps) s psi of the double-well term (>= max g'' = 1/2).
    ``area_correction`` projects each new shape back onto the initial enclosed
    area (the exact dynamics conserve it; the projection removes the O(dt^2)
    drift of the time stepping without lowering its order, and its running sum
    is recorded as the diagnostic ``area_correction``). ``filter_order`` p > 0 filters
    the explicit part G = F + lam theta of the tangent-angle equation by
    exp(-10 (|m| / (N/2))^p), m the mode (an exponential filter as in Hou, Lowengrub &
    Shelley, J. Comput. Phys. 114 (1994) 312; the publication's code filters so with
    p = 25): the modes near N/2 decay at their implicit rate instead of growing
    (docs/numerics.md, "Stalled runs"). It changes the solution where the top modes carry
    content (docs/numerics.md, "A filter"); 0, the default, filters nothing.
    ``dealias`` r > 1 computes the right-hand sides on r N nodes from the state's
    trigonometric interpolant and keeps their lowest N modes (the 3/2 rule at r = 1.5, as
    in Orszag, J. Atmos. Sci. 28 (1971) 1074): the products of the rates (curvature
    squared, the bending moment, the double well, e^{i theta}) no longer fold their
    modes above N/2 back onto the resolved ones, which is what makes the sharp tips of
    deflated vesicles grow spurious content near N/2 (docs/numerics.md, "De-aliased
    rates"); 1, the default, computes them on the N nodes.
    ``startup_dt`` > 0 takes an adaptive run's first ``startup_time`` in fixed steps of
    startup_dt (cut to land on samples and on startup_time), then hands over to the
    controller: the publication's fixed dt = 1e-5 through the start-up transient, which
    selects the attractor where several coexist (docs/numerics.md, "A start-up at a fixed
    step"); 0, the default, controls every step.
    ``scheme``: "sbdf2" (the default: variable-step SBDF2, fixed or under error control) or
    "ifab2", the publication's time integration as its authors' code does it (a second-order
    integrating factor with Adams-Bashforth for the tangent angle, 20 such substeps of the phase
    field with the shape frozen, Adams-Bashforth for the position; fixed steps only;
    solver/timestepping.py, docs/numerics.md "The publication's scheme").
    """

    N: int = 128
    N_max: int = 0
    resize_tail: float = 1e-4
    shrink_after: float = 20.0
    dt: float = 1e-3
    rtol: float | None = None
    atol: float = 0.0
    dt_max: float = 0.05
    dt_initial: float = 1e-6
    bending_stabilization: float = 1.0
    phase_stabilization: float = 1.0
    area_correction: bool = True
    filter_order: int = 0
    dealias: float = 1.0
    startup_dt: float = 0.0
    startup_time: float = 0.0
    scheme: str = "sbdf2"

    #: the time integrations numerics.scheme names
    SCHEMES = ("sbdf2", "ifab2")
    #: the padding factors numerics.dealias may take
    DEALIAS_FACTORS = (1.0, 1.5, 2.0)

    def __post_init__(self) -> None:
        _require(isinstance(self.N, int) and not isinstance(self.N, bool),
                 f"numerics.N = {self.N!r}: must be an integer")
        _require(self.N >= 16, f"numerics.N = {self.N}: too small, use at least 16 points")
        _require(self.N <= 4096, f"numerics.N = {self.N}: more than 4096 points is not supported "
                 "(the Stokeslet matrix is dense)")
        _require(self.N % 2 == 0, f"numerics.N = {self.N}: must be even")
        _require(isinstance(self.N_max, int) and not isinstance(self.N_max, bool),
                 f"numerics.N_max = {self.N_max!r}: must be an integer")
        if self.N_max:
            _require(self.N_max > self.N, f"numerics.N_max = {self.N_max}: must be above N = {self.N} "
                     "(or 0: N fixed)")
            _require(self.N_max <= 4096, f"numerics.N_max = {self.N_max}: more than 4096 points is not supported")
            _require(self.N_max % 2 == 0, f"numerics.N_max = {self.N_max}: must be even")
        _finite(self)
        _require(0 < self.resize_tail < 1, f"numerics.resize_tail = {self.resize_tail}: must lie in (0, 1)")
        _require(self.shrink_after > 0, f"numerics.shrink_after = {self.shrink_after}: must be > 0 (shear times)")
        _require(self.dt > 0, f"numerics.dt = {self.dt}: must be > 0")
        if self.rtol is not None:
            _require(isinstance(self.rtol, float) and math.isfinite(self.rtol),
                     f"numerics.rtol = {self.rtol!r}: must be a number")
            _require(1e-10 <= self.rtol <= 0.1, f"numerics.rtol = {self.rtol:g}: must lie in [1e-10, 0.1]")
        _require(self.atol >= 0, f"numerics.atol = {self.atol}: must be >= 0")
        _require(self.dt_max > 0, f"numerics.dt_max = {self.dt_max}: must be > 0")
        _require(0 < self.dt_initial <= self.dt_max,
                 f"numerics.dt_initial = {self.dt_initial}: must lie in (0, numerics.dt_max = {self.dt_max}]")
        _require(self.bending_stabilization >= 1.0,
                 f"numerics.bending_stabilization = {self.bending_stabilization}: must be >= 1 "
                 "(smaller values make the time stepping unstable)")
        _require(isinstance(self.filter_order, int) and not isinstance(self.filter_order, bool)
                 and (self.filter_order == 0 or 8 <= self.filter_order <= 64),
                 f"numerics.filter_order = {self.filter_order!r}: must be 0 (no filter) or an integer in [8, 64] "
                 "(25 filters the top fifth of the modes)")
        _require(isinstance(self.dealias, (int, float)) and not isinstance(self.dealias, bool)
                 and self.dealias in self.DEALIAS_FACTORS,
                 f"numerics.dealias = {self.dealias!r}: must be 1 (rates on the N nodes), 1.5 (the 3/2 rule) or 2")
        object.__setattr__(self, "dealias", float(self.dealias))     # 2 and 2.0: one fingerprint
        if self.dealias != 1.0:
            largest = max(self.N, self.N_max)
            _require(all(round(self.dealias * n) % 2 == 0 and self.dealias * n == round(self.dealias * n)
                         for n in (self.N, largest)),
                     f"numerics.dealias = {self.dealias}: {self.dealias} N must be an even integer "
                     f"(N = {self.N}{f', N_max = {self.N_max}' if self.N_max else ''}; "
                     "use multiples of 4 with the 3/2 rule)")
            _require(self.dealias * largest <= 4096,
                     f"numerics.dealias = {self.dealias}: the rates would be computed on "
                     f"{self.dealias * largest:g} > 4096 nodes (the Stokeslet matrix is dense)")
        _require(self.startup_dt >= 0 and self.startup_time >= 0,
                 f"numerics.startup_dt = {self.startup_dt}, startup_time = {self.startup_time}: must be >= 0")
        if self.startup_dt or self.startup_time:
            _require(self.rtol is not None, "numerics.startup_dt: a fixed-step start-up belongs to an adaptive run "
                                            "(give numerics.rtol; a fixed-step run takes numerics.dt throughout)")
            _require(0 < self.startup_dt <= self.startup_time,
                     f"numerics.startup_dt = {self.startup_dt}, startup_time = {self.startup_time}: give both, "
                     "with 0 < startup_dt <= startup_time")
        _require(self.scheme in self.SCHEMES,
                 f"numerics.scheme = {self.scheme!r}: must be one of {', '.join(map(repr, self.SCHEMES))}")
        if self.scheme == "ifab2":
            _require(self.rtol is None, "numerics.scheme = \"ifab2\": the publication's scheme takes fixed steps "
                     "(give dt, not rtol)")
        _require(self.phase_stabilization >= 0.5,
                 f"numerics.phase_stabilization = {self.phase_stabilization}: must be >= 0.5 "
                 "(max g'' on [0, 1])")

    def grid(self) -> str:
        """``N = 128``, or where N adapts ``N = auto (64-512)``; with de-aliased rates ``, rates on 2 N``."""
        grid = f"N = auto ({self.N}-{self.N_max})" if self.adaptive_N else f"N = {self.N}"
        return grid + dealias_label(self.dealias)

    @property
    def adaptive_N(self) -> bool:
        """True when N adapts during the run, from N up to ``N_max`` (numerics.N = "auto")."""
        return self.N_max > 0

    def step_text(self) -> str:
        """How the step is taken, for a header line: ``rtol = 0.001`` or ``dt = 1e-05`` (with the scheme
        where it is not SBDF2)."""
        text = f"rtol = {self.rtol:g}" if self.adaptive else f"dt = {self.dt:g}"
        return text + (", the publication's scheme (ifab2)" if self.scheme == "ifab2" else "")

    @property
    def adaptive(self) -> bool:
        """True when the step is chosen by error control (``rtol`` set)."""
        return self.rtol is not None

    @property
    def fixed_dt(self) -> float:
        """The fixed step, 0 in adaptive runs (no step is fixed)."""
        return 0.0 if self.adaptive else self.dt


@dataclass(frozen=True)
class RunControl:
    """How long to run and what to record.

    Intervals are in simulated time and are rounded to whole steps.
    ``checkpoint_wall`` additionally writes a checkpoint whenever that many
    wall-clock seconds have passed since the last one (0 disables it).
    A run stops as under-resolved when the top third of the Fourier modes of
    theta_tilde or psi holds more than ``max_spectral_tail`` of its variation
    (3e-3: N = 32 at Delta = 0.194 and N = 64 at Delta = 2.3 exceed it, the
    resolutions that agreed with finer runs stay below; docs/numerics.md).
    With ``until_decided`` the run stops as soon as the classifier of ``hpcves
    analyze`` decides it (decision.py): tank-treading steady for
    ``decided_shear_times`` shear times, phase-treading or tumbling over
    ``decided_periods`` settled periods, asked every ``decision_samples``
    samples; ``t_end`` is then a cap.
    An adaptive-step run stops as stalled when it has taken more than
    ``max_steps_per_shear_time`` steps per shear time (per time unit below S = 1)
    of one sample interval: the step has collapsed, as it did where aliasing drove
    the top modes of sharp deflated shapes (numerics.dealias removes that; healthy
    runs stay below 1.6e4 at rtol = 1e-3, their start-up included, whose steps grow
    as 1 / rtol below that -- and so does the watch's floor; docs/numerics.md,
    "Stalled runs"; 0: no watch).
    A run stops as diverged when the relative area or length error exceeds
    ``max_area_error`` / ``max_length_error``, when one step needs the area
    projection to undo a relative change above ``max_area_correction``, when
    psi leaves [``psi_min``, ``psi_max``] or when anything becomes NaN.
    The start-up relaxation of the initial ellipse needs per-step corrections
    up to ~7e-3 in its first steps (Delta = 2.3, S = 5, dt = 2e-4; Delta = 0.94,
    dt = 1e-3: 5e-3), and below 1e-7 once the shape has relaxed (t > 0.05);
    the bound is a guard against runaway steps, well above both.
    """

    t_end: float = 1.0
    sample_interval: float = 0.01
    snapshot_interval: float = 0.1
    checkpoint_interval: float = 0.5
    checkpoint_wall: float = 300.0
    max_area_error: float = 1e-3
    max_length_error: float = 1e-3
    max_area_correction: float = 0.05
    psi_min: float = -0.25
    psi_max: float = 1.1
    max_spectral_tail: float = 3e-3
    max_steps_per_shear_time: float = 2e5
    until_decided: bool = False
    decided_shear_times: float = 100.0
    decided_periods: float = 10.0
    decision_samples: int = 100

    def __post_init__(self) -> None:
        _finite(self)
        _require(self.t_end > 0, f"run.t_end = {self.t_end}: must be > 0")
        _require(0 < self.max_spectral_tail <= 1,
                 f"run.max_spectral_tail = {self.max_spectral_tail}: must lie in (0, 1]")
        _require(self.max_steps_per_shear_time >= 0,
                 f"run.max_steps_per_shear_time = {self.max_steps_per_shear_time}: must be >= 0 (0: no watch)")
        _require(self.decided_shear_times > 0, f"run.decided_shear_times = {self.decided_shear_times}: must be > 0")
        _require(self.decided_periods >= 1, f"run.decided_periods = {self.decided_periods}: must be >= 1")
        _require(isinstance(self.decision_samples, int) and self.decision_samples >= 1,
                 f"run.decision_samples = {self.decision_samples!r}: must be an integer >= 1")
        for name in ("sample_interval", "snapshot_interval", "checkpoint_interval"):
            value = getattr(self, name)
            _require(value > 0, f"run.{name} = {value}: must be > 0")
        _require(self.checkpoint_wall >= 0, f"run.checkpoint_wall = {self.checkpoint_wall}: must be >= 0")
        _require(self.max_area_error > 0, f"run.max_area_error = {self.max_area_error}: must be > 0")
        _require(self.max_length_error > 0, f"run.max_length_error = {self.max_length_error}: must be > 0")
        _require(self.max_area_correction > 0,
                 f"run.max_area_correction = {self.max_area_correction}: must be > 0")
        _require(self.psi_min < 0 < 1 < self.psi_max,
                 f"run.psi_min, run.psi_max = {self.psi_min}, {self.psi_max}: need psi_min < 0 and psi_max > 1")


@dataclass(frozen=True)
class Case:
    """One simulation: physics, numerics and run control, checked together."""

    physics: Physics = field(default_factory=Physics)
    numerics: Numerics = field(default_factory=Numerics)
    run: RunControl = field(default_factory=RunControl)

    def __post_init__(self) -> None:
        p, r = self.physics, self.run
        if not p.homogeneous:
            amplitude = p.phase_spread
            _require(
                r.psi_min < p.psi_bar - amplitude and p.psi_bar + amplitude < r.psi_max,
                f"physics.psi_bar = {p.psi_bar} with physics.delta = {p.delta}: the initial psi "
                f"spans [{p.psi_bar - amplitude:.3g}, {p.psi_bar + amplitude:.3g}], outside the "
                f"allowed range [{r.psi_min}, {r.psi_max}] (run.psi_min, run.psi_max)",
            )
        if self.numerics.adaptive_N:
            _require(self.numerics.resize_tail < r.max_spectral_tail,
                     f"numerics.resize_tail = {self.numerics.resize_tail:g}: must be below run.max_spectral_tail = "
                     f"{r.max_spectral_tail:g} (N grows before the watch would stop the run as under-resolved)")
        if self.numerics.adaptive:
            return
        _require(self.run.sample_interval >= self.numerics.dt,
                 f"run.sample_interval = {r.sample_interval} is shorter than numerics.dt = {self.numerics.dt}")
        _require(self.run.t_end >= self.numerics.dt,
                 f"run.t_end = {r.t_end} is shorter than numerics.dt = {self.numerics.dt}")
        steps = r.t_end / self.numerics.dt
        _require(steps <= MAX_STEPS,
                 f"run.t_end / numerics.dt = {r.t_end:g} / {self.numerics.dt:g} = {steps:.3g} time steps for one "
                 f"case: more than {MAX_STEPS:.0e} is surely a mistake ({steps * 2.5e-4 / 86400:.3g} days of one "
                 "core at the fastest step, N = 32)")

    @property
    def n_steps(self) -> int:
        """Number of time steps to reach t_end (t_end rounded to a whole step); fixed-step runs only."""
        _require(not self.numerics.adaptive, "an adaptive run has no fixed number of steps")
        return max(1, round(self.run.t_end / self.numerics.dt))

    @property
    def settled_step(self) -> float:
        """The step the run takes once past its start: dt, or for an adaptive run a guess.

        Steps never cross sample times, and the accurate step shrinks about as 1 / S and
        as rtol^(1/3) (docs/numerics.md, "Planning a campaign": 2.0-2.4 times the steps for
        rtol = 1e-3 as for 1e-2), so the guess is
        min(sample_interval, dt_max, 0.05 (rtol / 0.01)^(1/3) / S).
        """
        if not self.numerics.adaptive:
            return self.numerics.dt
        S = max(self.physics.shear_rate, 1.0)
        accurate = 0.05 * (self.numerics.rtol / 0.01) ** (1.0 / 3.0) / S
        return min(self.run.sample_interval, self.numerics.dt_max, accurate)

    @property
    def estimated_steps(self) -> float:
        """Steps the run will take: n_steps, or for an adaptive run t_end / :attr:`settled_step`
        (for ordering work and for ``hpcves campaign --plan``)."""
        if not self.numerics.adaptive:
            return float(self.n_steps)
        return self.run.t_end / self.settled_step

    def every(self, interval: float) -> int:
        """An interval in simulated time as a whole number of steps (>= 1)."""
        return max(1, round(interval / self.numerics.dt))

    def to_dict(self) -> dict:
        return {"physics": _values(self.physics), "numerics": _values(self.numerics), "run": _values(self.run)}

    def significant(self) -> dict:
        """:meth:`to_dict` without the options that this run does not use: the adaptive options
        of a fixed-step run, dt of an adaptive one, the decision rules of a run to t_end, the
        resolution watch at its default (what a study's fingerprint covers, so that files written
        before these options existed keep theirs; the linear bending law and the ellipse, which they all ran)."""
        out = self.to_dict()
        unused = ("dt",) if self.numerics.adaptive else ("rtol", "atol", "dt_max", "dt_initial")
        if not self.numerics.adaptive_N:
            unused += ("N_max", "resize_tail", "shrink_after")     # N fixed, as in files from before the option
        if not self.numerics.filter_order:
            unused += ("filter_order",)                            # no filter, as in files from before the option
        if self.numerics.dealias == 1.0:
            unused += ("dealias",)                                 # rates on the N nodes, likewise
        if not self.numerics.startup_dt:
            unused += ("startup_dt", "startup_time")               # no fixed-step start-up, likewise
        if self.numerics.scheme == "sbdf2":
            unused += ("scheme",)                                  # hpcves's own scheme, likewise
        for key in unused:
            del out["numerics"][key]
        if not self.run.until_decided:
            for key in ("until_decided", "decided_shear_times", "decided_periods", "decision_samples"):
                del out["run"][key]
        if self.run.max_spectral_tail == RunControl.max_spectral_tail:
            del out["run"]["max_spectral_tail"]       # the default watch: as files from before it
        if self.run.max_steps_per_shear_time == RunControl.max_steps_per_shear_time or not self.numerics.adaptive:
            del out["run"]["max_steps_per_shear_time"]    # likewise (and a fixed step cannot stall)
        if not self.physics.contrast:                 # equal viscosities: as files from before the option
            del out["physics"]["viscosity_ratio"]
        if self.physics.bending_law == "linear":      # the law of files from before the option
            del out["physics"]["bending_law"], out["physics"]["bending_width"]
        if self.physics.initial_shape == "ellipse":   # the start of files from before the option
            del out["physics"]["initial_shape"]
        if self.physics.initial_shape != "stored":
            for key in ("stored_file", "stored_case", "stored_time"):
                del out["physics"][key]
        if self.physics.initial_phase == "published":  # likewise the initial phase
            for key in ("initial_phase", "phase_domains", "phase_center", "phase_seed"):
                del out["physics"][key]
        return out

    def flat(self) -> dict:
        """``{"physics.shear_rate": 10.0, ...}``: one key per parameter (HDF5 attributes; an unset
        option such as rtol of a fixed-step run is NaN)."""
        return {f"{group}.{key}": (math.nan if value is None else value) for group, values in self.to_dict().items()
                for key, value in values.items()}


def _values(parameters) -> dict:
    """{field: value} of a parameter dataclass: ``dataclasses.asdict`` without its deep copy (every
    value is a scalar; the copy was a tenth of laying out a campaign's case)."""
    return {f.name: getattr(parameters, f.name) for f in fields(parameters)}


def dealias_label(dealias: float) -> str:
    """``, rates on 2 N`` for numerics.dealias = 2; nothing for rates on the N nodes."""
    return f", rates on {dealias:g} N" if dealias != 1.0 else ""


#: the largest shear rate accepted: in units of bending, S = 1e6 leaves the membrane's forces at 1e-6 of the
#: shear's stress (the publication's go to 350)
MAX_SHEAR_RATE = 1e6
#: no parameter of the model is meaningful beyond this magnitude (1e26 was accepted and failed at t = 0)
MAX_MAGNITUDE = 1e12


def _finite(obj) -> None:
    group = type(obj).__name__.lower()
    group = {"runcontrol": "run"}.get(group, group)
    for f in fields(obj):
        value = getattr(obj, f.name)
        if isinstance(value, float):
            _require(math.isfinite(value), f"{group}.{f.name} = {value}: must be a finite number")
            _require(abs(value) <= MAX_MAGNITUDE,
                     f"{group}.{f.name} = {value:g}: beyond {MAX_MAGNITUDE:g}, surely a mistake")
