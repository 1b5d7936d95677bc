"""Second-order, nonstiff time stepping of the two-phase vesicle.

Unknowns:

* theta_tilde = theta - 2 pi alpha, the periodic part of the tangent angle at N
  points equispaced in arclength s = L alpha (the *nodes*);
* center, the mean position of the nodes;
* shift, the arclength fraction a(t) by which the material has moved past the
  nodes: node alpha carries the material label alpha - a(t);
* psi, the soft-phase fraction at the nodes.

The nodes move with the membrane's normal velocity and with its tangential
velocity minus its mean V = mean(u . s): X_t = u - V s. Inextensibility keeps
them equispaced and a uniform shift keeps them material up to a(t), so a
tank-treading vesicle is *stationary* in this frame. Relative to the nodes the
material moves uniformly at speed V, so psi is advected by -V psi_s.

The phase pattern, though, may be at rest in neither frame: in phase-treading
it moves through the material at nearly the membrane speed and, during slips,
through the nodes too; with domains carried by the membrane it moves with the
material. Multistep schemes damp and disperse whatever travels through their
frame, so each psi step is taken in the frame of the pattern itself: a frame
moving at W relative to the nodes, W the pattern's velocity over the last
step (cross-correlation of psi^n and psi^{n-1}); docs/numerics.md ("Unknowns
and frame") compares the three frames.

Equations (L constant):

    theta_t  = -n . d(u - V s)/ds            (= -n . du/ds - V H, H = theta_s)
    psi_t    = nu d^2 mu / ds^2 - V psi_s
    center_t = mean(u)                       (mean(s) = 0 on a closed curve)
    a_t      = V / L

The stiff linear parts are implicit and the rest explicit (variable-step SBDF2
/ IMEX BDF2, Wang & Ruuth, J. Comput. Math. 26 (2008) 838; Dedalus's SBDF2):
with k = t_{n+1} - t_n and the step ratio w = k / k_{n-1},

    ((1 + 2w)/(1 + w) y^{n+1} - (1 + w) y^n + w^2/(1 + w) y^{n-1}) / k
        = -lam y^{n+1} + (1 + w) G^n - w G^{n-1},      G = F(y) + lam y,

with F the full right-hand side (for psi without the advection, which is
wholly implicit; with numerics.dealias = r, F evaluated on r N nodes from the
state's trigonometric interpolant and truncated to the N modes, so that its
products do not alias). At w = 1 it is (3 y^{n+1} - 4 y^n + y^{n-1}) / (2k) =
-lam y^{n+1} + 2 G^n - G^{n-1} (the same floating-point operations: fixed-step
runs are unchanged bit for bit). Variable-step BDF2 is zero-stable for
w < 1 + sqrt 2; the step controller (stepcontrol.py) keeps w <= 2. The local
error estimate is the difference between the step and the quadratic through
the last three levels (:class:`Estimate`). The stiff operators lam:

    theta:  lam = c max(B1, B2) |k|^3 / 4 (diagonal; the small-scale bending
            response, 1/(4|k|) being the single-layer symbol of a flat membrane);
    psi:    in the pattern frame (see :meth:`Solver._sbdf2_phase`), J(psi*) + (V* - W) D:
            the Jacobian of nu d^2 mu/ds^2 at the prediction psi* (circulant plus low rank, see
            phasefield.LinearizedImplicit) plus the advection at V* - W,
            V* = (1 + w) V^n - w V^{n-1}, so that the stiff double well is implicit to
            O((psi^{n+1} - psi*)^2).

The splitting of the variable-coefficient bending operator into a constant
implicit part c >= B(psi) and an explicit rest is stable for SBDF2 (amplification
<= 1 for all k dt when B <= 1.1 c; see docs/numerics.md). While the phase field
is still a mixture (long spinodal stretches or overshoots at level n-1, n or in
the prediction -- the first ~10 steps from the initial condition) -- or when the linearly
implicit step lands outside [-0.1, 1.1], which happens when spinodal growth
faster than 1/dt makes c I + J nearly singular -- psi takes a
linearly stabilised IMEX Euler step
instead, lam = nu (a0 eps k^4 + (a0/eps) s k^2) + i k V, which is robust there; a few
first-order steps in that transient cost O(dt^2) globally. The first step is
Richardson-extrapolated IMEX Euler (second order). After each step the tangent
angle is projected onto resolved modes, closed curves and (by default) the
initial area, and the mean of psi -- the mass int psi ds -- is carried over.

numerics.scheme = "ifab2" takes the publication's own step instead (integrating factor and
Adams-Bashforth, :meth:`Solver._ifab2`), for reproducing its figures as they were computed.

A :class:`State` holds everything a step needs, including the previous level
and the previous right-hand side, so a checkpoint of it resumes bit for bit.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from hpcves.model import continuation, geometry, phasefield
from hpcves.model.flow import Flow, MembraneFlow, TensionSolveError
from hpcves.model.forces import bending_energy, phase_energy
from hpcves.model.geometry import Shape
from hpcves.model.params import Case, ConfigError
from hpcves.numerics.spectral import Spectral, resample, spectral_tail

#: how a solver computes its rates and SBDF2 steps (Solver's ``engine``)
ENGINES = ("compiled", "numpy")
_COMPILED = None


def compiled_kernels():
    """solver/compiled.py, imported on first use (it imports numba: ~0.15 s, and loads the kernels);
    a global afterwards, since an import statement costs ~1 us on every call of a step."""
    global _COMPILED
    if _COMPILED is None:
        from hpcves.solver import compiled
        _COMPILED = compiled
    return _COMPILED


#: arguments of length 0 where a compiled kernel's array is absent (None in the numpy path)
EMPTY = np.empty(0)
EMPTY_SPECTRUM = np.empty(0, dtype=np.complex128)


#: alpha of the exponential filter exp(-alpha (|m| / (N/2))^p), the publication's code's (4.5e-5 at m = N/2)
FILTER_STRENGTH = 10.0


@dataclass(frozen=True)
class Rates:
    """Right-hand sides F at one time level, and the flow they came from."""

    theta: np.ndarray               # d theta_tilde / dt at the nodes
    psi: np.ndarray                 # nu d^2 mu / ds^2 at the nodes (psi_t without the advection)
    center: complex
    shift: float                    # d a / dt = V / L
    mean_tangential_velocity: float  # V
    flow: Flow
    shape: Shape
    psi_s: np.ndarray               # psi_s and mu at the nodes
    mu: np.ndarray | None
    psi_hat: np.ndarray | None = None   # rfft of the state's psi (two-phase only)


@dataclass(frozen=True)
class State:
    """The solution after ``step`` steps, at time ``t``, and the multistep history.

    ``dt_prev`` is the length of the step that led here (k_{n-1}); NaN at the start.
    ``error`` (that step's error estimate against the tolerance) and ``dt_next``
    (the step proposed next) are the step controller's memory (stepcontrol.py);
    NaN in fixed-step runs.
    """

    step: int
    theta: np.ndarray                 # theta_tilde at the nodes
    psi: np.ndarray                   # psi at the nodes
    center: complex
    shift: float = 0.0
    area_correction: float = 0.0      # running sum of relative area corrections
    prev_theta: np.ndarray | None = None       # level n-1 (None at step 0)
    prev_psi: np.ndarray | None = None
    prev_center: complex | None = None
    prev_shift: float | None = None
    prev_rate_theta: np.ndarray | None = None  # F at level n-1
    prev_rate_psi: np.ndarray | None = None
    prev_rate_center: complex | None = None
    prev_rate_shift: float | None = None
    t: float = 0.0
    dt_prev: float = float("nan")
    prev2_theta: np.ndarray | None = None      # level n-2 (None before step 2): for the error estimate only
    prev2_psi: np.ndarray | None = None
    dt_prev2: float = float("nan")
    error: float = float("nan")
    dt_next: float = float("nan")
    quiet_since: float = float("nan")          # N adapting: since when a smaller grid would do (resolution.py)

    @property
    def N(self) -> int:
        """The nodes of this state."""
        return self.theta.size

    ARRAYS = ("theta", "psi", "prev_theta", "prev_psi", "prev_rate_theta", "prev_rate_psi",
              "prev2_theta", "prev2_psi")
    SCALARS = ("center", "shift", "area_correction", "prev_center", "prev_shift",
               "prev_rate_center", "prev_rate_shift", "t", "dt_prev", "dt_prev2", "error", "dt_next")


@dataclass(frozen=True)
class Coefficients:
    """Variable-step SBDF2 for the step ratio w = k / k_{n-1}:

        implicit * y^{n+1} / k = (current * y^n - previous * y^{n-1}) / k
                                 + current * G^n - w * G^{n-1}  (- lam y^{n+1}),

    implicit = (1 + 2w)/(1 + w), current = 1 + w, previous = w^2/(1 + w);
    at w = 1: 3/2, 2, 1/2 (all exact in binary).
    """

    w: float
    implicit: float
    current: float
    previous: float

    @classmethod
    def for_ratio(cls, w: float) -> "Coefficients":
        return cls(w=w, implicit=(1.0 + 2.0 * w) / (1.0 + w), current=1.0 + w, previous=w * w / (1.0 + w))

    def explicit(self, y, y_prev, F, F_prev, k):
        """(current y^n - previous y^{n-1}) / k + current F^n - w F^{n-1}: the explicit side over k."""
        return (self.current * y - self.previous * y_prev) / k + self.current * F - self.w * F_prev

    def extrapolate(self, y, y_prev):
        """y* = (1 + w) y^n - w y^{n-1}: linear extrapolation to t_{n+1}, the predictor."""
        return self.current * y - self.w * y_prev


@dataclass(frozen=True)
class Estimate:
    """A step's local error estimate: y^{n+1} - p, field by field, with p a predictor of ``order`` - 1.

    From step 2 on, p is the quadratic through the levels n, n-1, n-2 evaluated
    at t_{n+1} (Milne's device):

        p = l0 y^n + l1 y^{n-1} + l2 y^{n-2},
        l0 = (k + k1)(k + k1 + k2) / (k1 (k1 + k2)),  l1 = -k (k + k1 + k2) / (k1 k2),
        l2 = k (k + k1) / (k2 (k1 + k2)),             (k1 = k_{n-1}, k2 = k_{n-2}; 3, -3, 1 at equal steps)

    whose error k (k + k1)(k + k1 + k2) y_ttt / 6 is of the same order k^3 as
    SBDF2's local error, so y^{n+1} - p ~ C k^3 y_ttt tracks it (``order`` 3).
    At step 1 p is the linear extrapolation (1 + w) y^n - w y^{n-1}, and at
    step 0 the Richardson difference 4 (E(k/2)E(k/2) - E(k)) stands in; both
    are ~ k^2 y_tt (``order`` 2). psi is predicted in the pattern frame of the
    step. ``psi`` is None for a homogeneous vesicle. ``scale_theta`` /
    ``scale_psi`` are max(|y^n|_inf, |y^{n+1}|_inf) of each field, for
    relative tolerances.
    """

    theta: np.ndarray
    psi: np.ndarray | None
    scale_theta: float
    scale_psi: float
    order: int


def quadratic_weights(k: float, k1: float, k2: float) -> tuple[float, float, float]:
    """(l0, l1, l2): the quadratic through t_n, t_n - k1, t_n - k1 - k2, evaluated at t_n + k."""
    return ((k + k1) * (k + k1 + k2) / (k1 * (k1 + k2)), -k * (k + k1 + k2) / (k1 * k2),
            k * (k + k1) / (k2 * (k1 + k2)))


def _scale(a, b) -> float:
    return float(max(np.abs(a).max(), np.abs(b).max()))


class Solver:
    """One vesicle: operators precomputed for a :class:`Case`; steps are pure functions of a State."""

    def __init__(self, case: Case, fft_backend: str = "fftw", start: tuple | None = None, N: int | None = None,
                 reference: "Solver | None" = None, dealias: bool = True, engine: str | None = None):
        """``start``: (theta_tilde, psi) of another state to start from (continuation.carried_start),
        instead of the case's own initial shape and phase. ``N``: the nodes, when not numerics.N (N
        adapting: run/resolution.py); ``reference``: the solver the run started with, whose initial area
        (the area projection's target) and initial tails this one keeps. ``dealias`` False: rates on
        the N nodes whatever numerics.dealias says (the padded grid's own solver). ``engine``: "compiled"
        (solver/compiled.py; the default with the FFTW backend) or "numpy" (this module's own arithmetic,
        the reference; the default with the numpy backend)."""
        self.case = case
        if engine is None:
            engine = "compiled" if fft_backend == "fftw" else "numpy"
        if engine not in ENGINES:
            raise ValueError(f"unknown engine {engine!r} (use one of {ENGINES})")
        self.engine = engine
        #: B''(psi*) H^2 / 2 in the phase step's Jacobian (phasefield.LinearizedImplicit); False leaves it
        #: explicit, only to show what it does (tests/test_solver.py)
        self.phase_jacobian_bending = True
        self._kernels: tuple | None = None            # the compiled engine's operators, once built
        self._given_start = start
        self._fft_backend = fft_backend
        phys, num = case.physics, case.numerics
        self.dt = num.dt
        self.sp = Spectral(num.N if N is None else N, phys.length, backend=fft_backend)
        self.flow = MembraneFlow(phys, self.sp)
        k = self.sp.k
        self._resolved = np.ones_like(k)
        self._resolved[-2:] = 0.0                    # modes N/2 - 1 and N/2 of theta_tilde
        self.lam_theta = num.bending_stabilization * max(phys.B1, phys.B2) * k**3 / 4.0
        if phys.contrast:
            # the double layer is smooth: the high modes feel the contrast only through (1 + lambda) / 2
            self.lam_theta = self.lam_theta * (2.0 / (1.0 + phys.viscosity_ratio))
        #: the exponential filter of theta's explicit part (None: numerics.filter_order = 0)
        self._theta_filter = (np.exp(-FILTER_STRENGTH * (np.abs(k) / abs(k[-1])) ** num.filter_order)
                              if num.filter_order else None)
        self._theta_inverse_memo: tuple = (None, None)
        #: the nodes the rates are computed on (numerics.dealias N), and their solver once built
        self.padded_N = round(num.dealias * self.sp.N) if dealias else self.sp.N
        self._padded: Solver | None = None
        self._mobility_k2 = phys.mobility * self.sp.k2                   # symbol of nu d^2/ds^2
        if phys.homogeneous:
            self.lam_psi, self.cahn_hilliard = None, None
        else:
            self.lam_psi = phasefield.implicit_symbol(k, phys.mobility, phys.a0, phys.epsilon,
                                                      num.phase_stabilization)
            self.cahn_hilliard = phasefield.LinearizedImplicit(self.sp, phys.mobility, phys.a0, phys.epsilon)
        self._applicable_memo: tuple = ()
        #: e^{2 pi i j / N} at the nodes (the compiled sample's phase position)
        self.node_phase = np.exp(2j * np.pi * np.arange(self.sp.N) / self.sp.N)
        self._start_shape = None               # (theta_tilde, ellipse parameters t) of the start
        if reference is not None:
            self.area0, self.initial_tails = reference.area0, reference.initial_tails
            return
        start = self.initial_state()
        self.area0 = geometry.enclosed_area(start.theta + self.sp.circle_angle, self.sp)
        #: the spectral tails of the initial data (theta, psi): the ellipse's own, which its fast
        #: relaxation forgets (diagnostics.health measures the dynamics against the larger of these
        #: and run.max_spectral_tail)
        if self.engine == "compiled":     # as its samples measure them (diagnostics.sample)
            self.initial_tails = compiled_kernels().spectral_tails(start.theta, start.psi)
        else:
            self.initial_tails = (spectral_tail(self.sp.fft.rfft(start.theta), self.sp.N),
                                  spectral_tail(self.sp.fft.rfft(start.psi), self.sp.N))

    def at(self, N: int) -> "Solver":
        """This case's solver on N nodes, with this one's initial area and tails."""
        return self if N == self.sp.N else Solver(self.case, self._fft_backend, self._given_start, N=N, reference=self,
                                                  engine=self.engine)

    def resized(self, state: State, N: int) -> tuple["Solver", State]:
        """(a solver at N nodes, ``state`` on its nodes): every level and right-hand side of the
        multistep history resampled by Fourier interpolation (spectral.resample; exact for fields
        resolved on both grids), theta_tilde and its rate kept to the modes both grids resolve (the
        old grid's top two are invisible to its force and dropped from its steps) and level n's
        projected onto closed curves of the initial area as after every step (the area the new grid's
        quadrature gives the interpolated curve differs by the old grid's quadrature error: 3e-8 at
        Delta = 0.94 from 64 to 96 nodes); the scalars, the step controller's memory included, as they
        are, but for ``quiet_since``: the watch of a smaller grid starts over on the new one. The new
        solver keeps this one's initial area and tails (the same targets whatever the grid)."""
        if N == self.sp.N:
            return self, state
        solver = self.at(N)
        fft = solver.sp.fft
        arrays = {}
        for name in State.ARRAYS:
            value = getattr(state, name)
            if value is not None and "theta" in name:       # modes the old grid drops would be kept on a finer one
                value = resample(self.sp.project(value, self._resolved), N)
                if name == "theta":
                    value, _ = solver._project(fft.rfft(value))
                else:
                    value = solver.sp.project(value, solver._resolved)
            elif value is not None:
                value = resample(value, N)
            arrays[name] = value
        return solver, dataclasses.replace(state, **arrays, quiet_since=float("nan"))

    # ------------------------------------------------------------------ set-up
    def initial_state(self) -> State:
        """The ellipse of the case's length and excess length, or its smoothed form (physics.initial_shape);
        phase as in SPEC section 1. Or the given start carried over to this case (continuation.py)."""
        phys, sp = self.case.physics, self.sp
        if self._given_start is not None:
            if self._start_shape is None:
                self._start_shape = continuation.carried_start(*self._given_start, phys, sp, self._resolved)
            theta, psi = self._start_shape
            return State(step=0, theta=theta.copy(), psi=psi.copy(), center=0j)
        if phys.initial_shape == "stored":
            raise ConfigError("physics.initial_shape = \"stored\": the runner reads the stored state "
                              "(stored.read_stored_start) and gives it to the solver")
        if self._start_shape is None:          # once per solver: the smoothed shape takes ~30 ms
            a, b = geometry.ellipse_for_excess_length(phys.length, phys.excess_length)
            t, theta = geometry.ellipse_equal_arclength(a, b, sp.N)
            if phys.initial_shape == "smoothed":
                theta = geometry.smoothed_ellipse(a, b, sp.N)
            theta = sp.project(theta - sp.circle_angle, self._resolved) + sp.circle_angle
            self._start_shape = (geometry.close_curve(theta) - sp.circle_angle, t)
        theta, t = self._start_shape[0].copy(), self._start_shape[1]
        if phys.homogeneous:
            psi = np.full(sp.N, phys.psi_bar)
        else:
            coordinate = sp.alpha if phys.psi_init_coordinate == "arclength" else t / (2 * np.pi)
            if phys.initial_phase == "domains":
                psi = phasefield.domains_phase(phys.psi_bar, phys.delta, coordinate, phys.phase_domains,
                                               phys.phase_center)
            elif phys.initial_phase == "random":
                psi = phasefield.random_phase(phys.psi_bar, phys.delta, coordinate, phys.phase_seed)
            else:
                psi = phasefield.initial_phase(phys.psi_bar, phys.delta, coordinate)
        return State(step=0, theta=theta, psi=psi, center=0j)

    # ------------------------------------------------------------------ views of a state
    def time(self, state: State) -> float:
        return state.t

    def shape(self, state: State) -> Shape:
        return geometry.shape_from_angle(state.theta, state.center, self.sp)

    def energies(self, state: State) -> tuple[float, float]:
        """(E_b, E_psi) of a state."""
        phys, sp = self.case.physics, self.sp
        curvature = 2.0 * np.pi / sp.length + sp.ds(state.theta)
        E_b = bending_energy(curvature, state.psi, phys, sp.length)
        psi_s = np.zeros_like(state.psi) if phys.homogeneous else sp.ds(state.psi)
        return E_b, phase_energy(state.psi, psi_s, phys, sp.length)

    # ------------------------------------------------------------------ right-hand side
    def rates(self, state: State) -> Rates:
        """F(y): the full right-hand side at one level (psi: without the advection -V psi_s); with
        numerics.dealias, computed on the padded nodes and truncated to these (:meth:`_truncated`)."""
        if self.padded_N == self.sp.N:
            rates = self._rates_on_nodes(state.theta, state.psi, state.center)
        else:
            if self._padded is None:
                self._padded = Solver(self.case, self._fft_backend, N=self.padded_N, reference=self, dealias=False,
                                      engine=self.engine)
            M = self.padded_N
            rates = self._truncated(self._padded._rates_on_nodes(resample(state.theta, M), resample(state.psi, M),
                                                                 state.center), state)
        if self._theta_filter is not None:    # G = F + lam theta filtered: F <- rho (F + lam theta) - lam theta
            fft = self.sp.fft
            theta_hat = fft.rfft(state.theta)
            theta_t = fft.irfft(self._theta_filter * (fft.rfft(rates.theta) + self.lam_theta * theta_hat)
                                - self.lam_theta * theta_hat)
            rates = dataclasses.replace(rates, theta=theta_t)
        return rates

    def _rates_on_nodes(self, theta: np.ndarray, psi: np.ndarray, center: complex) -> Rates:
        """The right-hand side evaluated on this solver's nodes, products taken pointwise."""
        if self.engine == "compiled":
            return self._compiled_rates(theta, psi, center)
        sp, phys, fft = self.sp, self.case.physics, self.sp.fft
        shape = geometry.shape_from_angle(theta, center, sp)
        if phys.homogeneous:
            psi_s, psi_ss, psi_hat = np.zeros_like(psi), None, None
        else:
            psi_hat = fft.rfft(psi)
            psi_s = fft.irfft(sp.ik * psi_hat)
            psi_ss = fft.irfft(sp.k2 * psi_hat)
        flow = self.flow.solve(shape, psi, psi_s)
        V = float(np.real(np.vdot(shape.tangent, flow.velocity))) / sp.N
        # theta_t = -n . d/ds (X_t), X_t = u - V s the velocity of the nodes; the
        # derivative is taken of X_t as a whole, consistently with z = int e^{i theta} ds.
        node_velocity_s = sp.ds_complex(flow.velocity - V * shape.tangent)
        theta_t = (np.conj(shape.tangent) * node_velocity_s).imag     # -n . dX_t/ds, n = -i s
        if phys.homogeneous:
            psi_t, mu = np.zeros_like(psi), None
        else:
            mu = phasefield.chemical_potential(psi, psi_ss, shape.curvature, phys.bending_prime(psi),
                                               phys.a0, phys.epsilon)
            psi_t = fft.multiply(mu, self._mobility_k2)
        return Rates(theta=theta_t, psi=psi_t, center=complex(flow.velocity.sum() / sp.N),
                     shift=V / sp.length, mean_tangential_velocity=V, flow=flow,
                     shape=shape, psi_s=psi_s, mu=mu, psi_hat=psi_hat)

    def _truncated(self, padded: Rates, state: State) -> Rates:
        """Rates of the padded grid kept to the modes of these N nodes (spectral.resample): the
        fields F, the flow and mu; the shape and psi's derivative are those of ``state`` here."""
        sp, N, fft = self.sp, self.sp.N, self.sp.fft
        if self.case.physics.homogeneous:
            psi_s, psi_hat, psi_t, mu = np.zeros_like(state.psi), None, np.zeros_like(state.psi), None
        else:
            psi_hat = fft.rfft(state.psi)
            psi_s = fft.irfft(sp.ik * psi_hat)
            psi_t, mu = resample(padded.psi, N), resample(padded.mu, N)
        flow = Flow(velocity=resample(padded.flow.velocity, N), tension_eff=resample(padded.flow.tension_eff, N))
        return Rates(theta=resample(padded.theta, N), psi=psi_t, center=padded.center, shift=padded.shift,
                     mean_tangential_velocity=padded.mean_tangential_velocity, flow=flow,
                     shape=geometry.shape_from_angle(state.theta, state.center, sp), psi_s=psi_s, mu=mu,
                     psi_hat=psi_hat)

    # ------------------------------------------------------------------ the compiled engine
    def _operators(self) -> tuple:
        """(ops, phys, step_ops, ch): what solver/compiled.py's rates and sbdf2 take of this solver."""
        if self._kernels is None:
            sp, phys, flow, N = self.sp, self.case.physics, self.flow, self.sp.N
            slp = flow.slp
            iterations = MembraneFlow.MAX_ITERATIONS if phys.contrast else 0
            krylov = (np.empty((2 * N, 2 * N) if phys.contrast else (0, 0)),      # GMRES's workspace
                      np.empty((iterations + 1, 3 * N)), np.empty((iterations, 3 * N)))
            ops = (sp.circle_angle, sp.ik, sp.k2, sp.ikc, sp._inv_ikc, slp._base_w, slp._E, slp._c_dir,
                   slp._A_diag0, self._mobility_k2, flow._blocks, krylov)
            physics = (float(phys.length), float(phys.B1), float(phys.B2), phys.bending_law == "saturating",
                       float(phys.bending_width), float(phys.shear_rate), float(phys.a0), float(phys.epsilon),
                       float(phys.mobility), float(phys.viscosity_ratio))
            lam_psi = np.zeros_like(sp.k) if self.lam_psi is None else self.lam_psi
            step_ops = (self.lam_theta, self._resolved, lam_psi, sp._im2pi, sp._m2pi_powers[0].copy(),
                        max(1, int(0.125 * N)))
            ch = self.cahn_hilliard
            ch_ops = ((np.zeros_like(sp.k), sp.ik, np.zeros_like(sp.k), 0.0, 0.0, N + 1) if ch is None else
                      (ch._bulk, ch._ik, ch._c2_k2, float(ch._bending_scale), float(ch.cutoff), ch._run_points))
            self._kernels = (ops, physics, step_ops, ch_ops)
        return self._kernels

    def _compiled_rates(self, theta, psi, center) -> Rates:
        compiled = compiled_kernels()
        ops, physics, _, _ = self._operators()
        homogeneous = self.case.physics.homogeneous
        psi_hat, psi_s, psi_ss, z, tangent, curvature, dB, f_b, r2 = compiled.shape_rates(
            theta, psi, complex(center), homogeneous, ops, physics)
        log_r2 = np.log(r2, out=r2)
        try:
            left, cancelled, residual, theta_t, psi_t, center_rate, V, velocity, tension, mu = compiled.flow_rates(
                theta, psi, complex(center), homogeneous, ops, physics, log_r2, psi_hat, psi_s, psi_ss, z,
                tangent, curvature, dB, f_b)
        except np.linalg.LinAlgError:
            raise TensionSolveError.not_definite() from None
        if not residual <= MembraneFlow.GMRES_TOLERANCE:
            raise TensionSolveError.unconverged(residual)
        if left > MembraneFlow.UNRESOLVED * cancelled:
            raise TensionSolveError.unresolved(left / cancelled)
        return Rates(theta=theta_t, psi=psi_t, center=complex(center_rate), shift=V / self.sp.length,
                     mean_tangential_velocity=V, flow=Flow(velocity=velocity, tension_eff=tension),
                     shape=Shape(z=z, tangent=tangent, curvature=curvature), psi_s=psi_s,
                     mu=None if homogeneous else mu, psi_hat=None if homogeneous else psi_hat)

    def _compiled_sbdf2(self, state: State, rates: Rates, k: float, w: float):
        compiled = compiled_kernels()
        ops, physics, step_ops, ch_ops = self._operators()
        homogeneous = self.case.physics.homogeneous
        quadratic = state.prev2_theta is not None
        area0 = self.area0 if self.case.numerics.area_correction else float("nan")
        history = (state.prev2_theta, state.prev2_psi, float(state.dt_prev2)) if quadratic else (EMPTY, EMPTY, 1.0)
        try:
            theta, before, theta_error, theta_scale, psi, psi_error, psi_scale, order = compiled.sbdf2(
                state.theta, state.prev_theta, history[0], rates.theta, state.prev_rate_theta,
                state.psi, state.prev_psi, history[1], rates.psi, state.prev_rate_psi,
                EMPTY_SPECTRUM if rates.psi_hat is None else rates.psi_hat, rates.shape.curvature,
                float(rates.shift), float(state.prev_rate_shift), float(k), float(w), float(state.dt_prev),
                history[2], homogeneous, float(area0), self.phase_jacobian_bending, ops, step_ops, ch_ops, physics)
        except np.linalg.LinAlgError:
            raise ArithmeticError("Cahn-Hilliard step: singular linear system") from None
        correction = 0.0 if before != before else (self.area0 - before) / self.area0
        c = Coefficients.for_ratio(w)
        center = c.explicit(state.center, state.prev_center, rates.center, state.prev_rate_center, k) \
            * (k / c.implicit)
        shift = c.explicit(state.shift, state.prev_shift, rates.shift, state.prev_rate_shift, k) \
            * (k / c.implicit)
        estimate = Estimate(theta_error, None if homogeneous else psi_error, theta_scale, psi_scale, order)
        return theta, psi, center, shift, correction, estimate

    # ------------------------------------------------------------------ stepping
    def step(self, state: State, rates: Rates | None = None, k: float | None = None
             ) -> tuple[State, Rates, Estimate | None]:
        """Advance one step of length ``k`` (default: the fixed ``numerics.dt``).

        Returns the new state, the rates at the *old* level and the local error
        estimate (None from the publication's scheme, :meth:`_ifab2`, which takes fixed
        steps). ``rates`` may be passed if already computed for ``state`` (they
        are a pure function of it), so a rejected step retried with a smaller k
        costs no new flow solve. A state without history (step 0) is started
        by Richardson extrapolation of IMEX Euler, 2 E(k/2)E(k/2) - E(k), which
        is second-order accurate like the SBDF2 steps that follow. A fixed-step
        run lands on t = step * dt exactly; a variable one on t + k.
        """
        if rates is None:
            rates = self.rates(state)
        fixed = k is None
        if fixed:
            k = self.dt
        if self.case.numerics.scheme == "ifab2":     # fixed steps only (params.Numerics): no error estimate
            return self._ifab2(state, rates, k, fixed), rates, None
        if state.prev_theta is None:
            theta, psi, center, shift, correction, estimate = self._start(state, rates, k)
        else:
            w = 1.0 if fixed else k / state.dt_prev
            theta, psi, center, shift, correction, estimate = self._sbdf2(state, rates, k, w)
        t = (state.step + 1) * self.dt if fixed else state.t + k
        new = State(step=state.step + 1, theta=theta, psi=psi, center=center, shift=shift,
                    area_correction=state.area_correction + correction,
                    prev_theta=state.theta, prev_psi=state.psi, prev_center=state.center,
                    prev_shift=state.shift, prev_rate_theta=rates.theta, prev_rate_psi=rates.psi,
                    prev_rate_center=rates.center, prev_rate_shift=rates.shift, t=t, dt_prev=k,
                    prev2_theta=state.prev_theta, prev2_psi=state.prev_psi, dt_prev2=state.dt_prev,
                    quiet_since=state.quiet_since)
        return new, rates, estimate

    # ------------------------------------------------------------------ the publication's scheme
    #: the phase field's substeps in one step of the publication's scheme (its code's nloop)
    PHASE_SUBSTEPS = 20

    def _ifab2(self, state: State, rates: Rates, k: float, fixed: bool = True) -> State:
        """One step of the publication's scheme, as its authors' code takes it (numerics.scheme = "ifab2").

        In the frame of the material (node alpha of this solver carries the label alpha - a: the
        fields are translated by a^n on the way in and by a^{n+1} on the way out, exactly in
        Fourier space), with E = e^{-lam k}, lam = c max(B1, B2) |k|^3 / 4 and G = theta_t + lam
        theta (the material rate -n . du/ds = F + V theta_s, filtered as numerics.filter_order says):

            theta^{n+1} = E theta^n + k/2 (3 E G^n - E^2 G^{n-1})          (IF-AB2)
            a, center:  y^{n+1} = y^n + k/2 (3 y_t^n - y_t^{n-1})            (AB2)

        and psi in 20 substeps h = k/20 with the shape frozen at level n, E_h = e^{-lam_psi h},
        lam_psi = nu a0 eps |k|^4, N = nu d^2 mu/ds^2 + lam_psi psi (the history N^{j-1} carried
        from substep to substep and from step to step):

            psi^{j+1} = E_h psi^j + h/2 (3 E_h N^j - E_h^2 N^{j-1}).

        The first step is the integrating-factor Euler step, theta^1 = E (theta^0 + k G^0), and
        20 such substeps of psi. Linear propagator for theta and Adams-Bashforth positions:
        Hou, Lowengrub & Shelley, J. Comput. Phys. 114 (1994) 312; Sohn et al., J. Comput. Phys.
        229 (2010) 119; the code: quaife/brinkman, shuwang_code/shear1Ves.m. As in the rest of
        hpcves (unlike that code) the length is held fixed and theta is projected onto closed
        curves (and, with numerics.area_correction, onto the initial area). The state's
        prev_rate_theta and prev_rate_psi hold G^n and the last substep's N (at the nodes).
        """
        sp, fft, phys = self.sp, self.sp.fft, self.case.physics
        first = state.prev_theta is None
        to_material = sp.shift_symbol(-state.shift)
        V = rates.mean_tangential_velocity
        theta_hat = fft.rfft(state.theta)
        material_rate = fft.rfft(rates.theta) + V * (self._theta_filter if self._theta_filter is not None
                                                     else 1.0) * sp.ik * theta_hat
        G = material_rate + self.lam_theta * theta_hat
        E = np.exp(-self.lam_theta * k)
        if first:
            theta_new = E * (to_material * (theta_hat + k * G))
            shift = state.shift + k * rates.shift
            center = state.center + k * rates.center
        else:
            G_prev = sp.shift_symbol(-state.prev_shift) * fft.rfft(state.prev_rate_theta)
            theta_new = E * (to_material * (theta_hat + 1.5 * k * G)) - (0.5 * k) * (E * E) * G_prev
            shift = state.shift + 0.5 * k * (3.0 * rates.shift - state.prev_rate_shift)
            center = state.center + 0.5 * k * (3.0 * rates.center - state.prev_rate_center)
        to_nodes = sp.shift_symbol(shift)
        theta, correction = self._project(to_nodes * theta_new)
        psi, last_N = state.psi, None
        if not phys.homogeneous:
            psi_hat, last_N = self._ifab2_phase(fft.rfft(state.psi) * to_material,
                                                fft.irfft(to_material * fft.rfft(rates.shape.curvature)),
                                                None if first else
                                                to_material * fft.rfft(state.prev_rate_psi), k)
            psi = self._conserve(fft.irfft(to_nodes * psi_hat), state.psi)
            last_N = fft.irfft(to_nodes * last_N)
        return State(step=state.step + 1, theta=theta, psi=psi, center=center, shift=shift,
                     area_correction=state.area_correction + correction,
                     prev_theta=state.theta, prev_psi=state.psi, prev_center=state.center, prev_shift=state.shift,
                     prev_rate_theta=fft.irfft(G), prev_rate_psi=last_N, prev_rate_center=rates.center,
                     prev_rate_shift=rates.shift, t=(state.step + 1) * self.dt if fixed else state.t + k, dt_prev=k,
                     prev2_theta=state.prev_theta, prev2_psi=state.prev_psi, dt_prev2=state.dt_prev,
                     quiet_since=state.quiet_since)

    def _ifab2_phase(self, psi_hat, curvature, N_prev, k):
        """(psi^{n+1}, the last substep's N), spectra in the material frame: the 20 substeps of
        :meth:`_ifab2` at the frozen ``curvature``; IF-Euler substeps where ``N_prev`` is None."""
        sp, fft, phys = self.sp, self.sp.fft, self.case.physics
        lam = phys.mobility * phys.a0 * phys.epsilon * sp.k**4
        h = k / self.PHASE_SUBSTEPS
        E = np.exp(-lam * h)
        euler = N_prev is None
        for _ in range(self.PHASE_SUBSTEPS):
            psi = fft.irfft(psi_hat)
            mu = phasefield.chemical_potential(psi, fft.irfft(sp.k2 * psi_hat), curvature,
                                               phys.bending_prime(psi), phys.a0, phys.epsilon)
            N = self._mobility_k2 * fft.rfft(mu) + lam * psi_hat
            if euler:
                psi_hat = E * (psi_hat + h * N)
            else:
                psi_hat = E * (psi_hat + 1.5 * h * N) - (0.5 * h) * (E * E) * N_prev
            N_prev = N
        return psi_hat, N_prev

    def _sbdf2(self, state: State, rates: Rates, k: float, w: float):
        if self.engine == "compiled":
            return self._compiled_sbdf2(state, rates, k, w)
        fft = self.sp.fft
        c = Coefficients.for_ratio(w)
        explicit = c.explicit(state.theta, state.prev_theta, rates.theta, state.prev_rate_theta, k)
        theta_star = c.extrapolate(state.theta, state.prev_theta)
        theta_hat = (fft.rfft(explicit) + self.lam_theta * fft.rfft(theta_star)) * self._theta_inverse(c, k)
        theta, correction = self._project(theta_hat)
        quadratic = state.prev2_theta is not None
        if quadratic:
            l0, l1, l2 = quadratic_weights(k, state.dt_prev, state.dt_prev2)
            theta_predicted = l0 * state.theta + l1 * state.prev_theta + l2 * state.prev2_theta
        else:
            theta_predicted = theta_star
        if self.case.physics.homogeneous:
            psi, psi_error, psi_scale = state.psi, None, 0.0
        else:
            raw, psi_star, (to_n, to_prev, moved), fell_back = self._sbdf2_phase(state, rates, k, c)
            psi = self._conserve(raw, state.psi)
            if quadratic:                     # the three levels in the step's pattern frame
                to_prev2 = self.sp.shift_symbol(moved * (k + state.dt_prev + state.dt_prev2) / state.dt_prev)
                predicted = fft.irfft((l0 * to_n) * rates.psi_hat + (l1 * to_prev) * fft.rfft(state.prev_psi)
                                      + (l2 * to_prev2) * fft.rfft(state.prev2_psi))
            else:
                predicted = psi_star
            psi_error, psi_scale = psi - predicted, _scale(psi, state.psi)
            if fell_back:
                psi_error = self._followed_modes(psi_error, k)
        center = c.explicit(state.center, state.prev_center, rates.center, state.prev_rate_center, k) \
            * (k / c.implicit)
        shift = c.explicit(state.shift, state.prev_shift, rates.shift, state.prev_rate_shift, k) \
            * (k / c.implicit)
        estimate = Estimate(theta - theta_predicted, psi_error, _scale(theta, state.theta), psi_scale,
                            3 if quadratic else 2)
        return theta, psi, center, shift, correction, estimate

    def _theta_inverse(self, c: Coefficients, k: float) -> np.ndarray:
        """1 / (implicit / k + lam_theta): SBDF2's implicit theta side, kept for the last k and w."""
        key = (c.implicit, k)
        if self._theta_inverse_memo[0] != key:
            self._theta_inverse_memo = (key, 1.0 / (c.implicit / k + self.lam_theta))
        return self._theta_inverse_memo[1]

    def _sbdf2_phase(self, state: State, rates: Rates, k: float, c: Coefficients):
        """(psi^{n+1}, psi*, frame) at the nodes: one SBDF2 step in the frame of the phase pattern.

        The frame moves at W relative to the nodes, the velocity of the pattern
        over the last step (psi^n ~ psi^{n-1} displaced by W k_{n-1}, measured by
        cross-correlation), and meets the nodes at t_{n+1}; in it the levels n
        and n-1 are psi and F shifted by W k and W (k + k_{n-1}), and psi is
        advected at V* - W. Any W gives a consistent SBDF2 step (a Galilean change of
        frame for the three levels); W = the pattern velocity makes psi nearly
        steady in the frame, which is where multistep error is smallest. psi* is
        the predictor (1 + w) psi^n - w psi^{n-1} in that frame, at the nodes at t_{n+1};
        ``frame`` = (shift symbols of levels n and n-1, the pattern's shift over the last step);
        last, whether the stabilised Euler step stood in (the SBDF2 step was not applicable or not plausible).
        """
        sp, fft, ch = self.sp, self.sp.fft, self.cahn_hilliard
        L = sp.length
        psi_hat, prev_hat = rates.psi_hat, fft.rfft(state.prev_psi)       # rates are those of state
        moved = sp.displacement(state.psi, state.prev_psi, spectra=(psi_hat, prev_hat))   # W k_{n-1} / L
        W = L * moved / state.dt_prev
        if c.w == 1.0:
            to_n, to_prev = sp.shift_symbols(moved)
        else:
            to_n, to_prev = sp.shift_symbol(c.w * moved), sp.shift_symbol((1.0 + c.w) * moved)
        level_n = psi_hat * to_n
        level_prev = prev_hat * to_prev
        star_hat = c.current * level_n - c.w * level_prev
        psi_star = fft.irfft(star_hat)
        V_star = L * (c.current * rates.shift - c.w * state.prev_rate_shift)
        if ch.applicable(psi_star) and self._applicable(state.psi) and self._applicable(state.prev_psi):
            explicit_hat = (((c.current / k) * psi_hat + c.current * fft.rfft(rates.psi)) * to_n
                            - ((c.previous / k) * prev_hat + c.w * fft.rfft(state.prev_rate_psi)) * to_prev)
            psi = ch.solve_spectral(psi_star, star_hat, c.implicit / k, explicit_hat, V_star - W,
                                    self._bending_curvature(psi_star, rates.shape.curvature))
            if phasefield.plausible(psi):
                return psi, psi_star, (to_n, to_prev, moved), False
        return (self._stabilized_euler_phase(state.psi, rates.psi, k, V_star), psi_star, (to_n, to_prev, moved),
                True)

    def _start(self, state: State, rates: Rates, k: float):
        """Richardson extrapolation 2 E(k/2) E(k/2) - E(k) of IMEX Euler; the estimate 4 (E(k/2)E(k/2) - E(k))
        (IMEX Euler's local error k^2 y''/2 is twice the half steps' one: their difference is k^2 y''/4,
        scaled to the k^2 y'' that the predictor difference of the steps that follow measures)."""
        full = self._euler(state, rates, k)
        half = self._euler(state, rates, 0.5 * k)
        half = self._euler(half, self.rates(half), 0.5 * k)
        theta, correction = self._project(self.sp.fft.rfft(2.0 * half.theta - full.theta))
        if self.case.physics.homogeneous:
            psi, psi_error, psi_scale = state.psi, None, 0.0
        else:
            psi = self._conserve(2.0 * half.psi - full.psi, state.psi)
            psi_error, psi_scale = 4.0 * (half.psi - full.psi), _scale(psi, state.psi)
        estimate = Estimate(4.0 * (half.theta - full.theta), psi_error, _scale(theta, state.theta), psi_scale, 2)
        return (theta, psi, 2.0 * half.center - full.center, 2.0 * half.shift - full.shift, correction,
                estimate)

    def _euler(self, state: State, rates: Rates, dt: float) -> State:
        """IMEX Euler: (y1 - y0)/dt = -lam y1 + F(y0) + lam y0."""
        fft = self.sp.fft
        theta_hat = (fft.rfft(state.theta + dt * rates.theta) + dt * self.lam_theta * fft.rfft(state.theta)) \
            / (1.0 + dt * self.lam_theta)
        theta, _ = self._project(theta_hat)
        V = rates.mean_tangential_velocity
        if self.case.physics.homogeneous:
            psi = state.psi
        else:
            psi = None
            if self._applicable(state.psi):
                psi = self.cahn_hilliard.solve_linearized(state.psi, 1.0 / dt, state.psi / dt + rates.psi, V,
                                                          self._bending_curvature(state.psi, rates.shape.curvature))
            if psi is None or not phasefield.plausible(psi):
                psi = self._stabilized_euler_phase(state.psi, rates.psi, dt, V)
            psi = self._conserve(psi, state.psi)
        return State(step=state.step, theta=theta, psi=psi, center=state.center + dt * rates.center,
                     shift=state.shift + dt * rates.shift)

    def _bending_curvature(self, psi_star, curvature):
        """B''(psi*) H^2 / 2, the bending law's part of d mu / d psi for the Jacobian (None where B'' = 0,
        or where it is left out: ``phase_jacobian_bending``)."""
        if not self.phase_jacobian_bending:
            return None
        second = self.case.physics.bending_second(psi_star)
        return None if second is None else 0.5 * second * curvature * curvature

    def _applicable(self, psi) -> bool:
        """cahn_hilliard.applicable(psi), remembered for the last few levels.

        Each level is checked in two consecutive steps (as psi^n, then as
        psi^{n-1}); a state's arrays are never modified, so the answer is
        looked up by identity. Restarts recompute it: the same answer.
        """
        for array, answer in self._applicable_memo:
            if array is psi:
                return answer
        answer = self.cahn_hilliard.applicable(psi)
        self._applicable_memo = self._applicable_memo[-2:] + ((psi, answer),)
        return answer

    def _followed_modes(self, error, k: float) -> np.ndarray:
        """The part of a stabilised Euler step's error estimate in the modes the step follows in time.

        In a mode with k lam >> 1 that step's increment is (F / lam) / (1 + 1 / (k lam)) ~ F / lam
        whatever k is (the stabilisation slaves the mode), so its estimate there does not shrink with
        the step and a controller would reject every step (psi_bar = 0.48, Delta = 1.3, S = 5:
        21 rejections in a row at t = 2.81). The estimate keeps the modes with k lam <= 1, where the
        step is a consistent first-order step; the slaved ones are damped by the next steps.
        """
        fft = self.sp.fft
        return fft.irfft(fft.rfft(error) * (k * self.lam_psi <= 1.0))

    def _stabilized_euler_phase(self, psi, rate, dt, advection):
        """IMEX Euler with linear stabilisation and implicit advection at speed V = ``advection``:
        (1/dt + lam + i k V) psi_new = psi/dt + F + lam psi.

        Used while the phase field is far from separated (long spinodal stretches,
        overshoots), where it is robust and, for Cahn-Hilliard alone, energy stable;
        the linearly implicit SBDF2 step takes over once interfaces have formed.
        """
        fft = self.sp.fft
        damping = 1.0 + dt * (self.lam_psi + advection * self.sp.ik)
        return fft.irfft(fft.rfft(psi + dt * rate) / damping + fft.rfft(psi) * (dt * self.lam_psi / damping))

    def _project(self, theta_hat):
        """Project theta_tilde, given by its rfft ``theta_hat``, onto resolved modes, closed curves
        and (optionally) the initial area.

        Modes N/2 - 1 and N/2 of the tangent angle are invisible to the discrete
        force (multiplication by e^{i theta} moves them onto the complex Nyquist
        mode, which odd derivatives drop), so nothing damps them; theta_tilde is
        kept to modes |m| <= N/2 - 2. The curve is then closed and its area
        restored (geometry.project_closed). Returns (theta_tilde, relative area
        correction made).
        """
        sp = self.sp
        theta = sp.fft.irfft(self._resolved * theta_hat) + sp.circle_angle
        target = self.area0 if self.case.numerics.area_correction else None
        theta, before = geometry.project_closed(theta, sp, target)
        correction = 0.0 if before is None else (self.area0 - before) / self.area0
        return theta - sp.circle_angle, correction

    @staticmethod
    def _conserve(psi_new, psi_old):
        """Carry the mass int psi ds over exactly (it is conserved up to round-off anyway)."""
        return psi_new + (psi_old.sum() - psi_new.sum()) / psi_new.size
