"""The ONE problem builder of CiMPCC and MPCC (paper eq. 5 and 13), multiple shooting.

Layout of the decision vector, stage by stage as fatrop's structure detection needs it::

    w = [xa_0, ua_0, xa_1, ua_1, ..., xa_{N-1}, ua_{N-1}, xa_N]

with the augmented OCP state ``xa = [X, Y, phi, s, v_l_prev, delta_prev, v_p_prev]`` (the model
state plus the previous input, so the delta-u cost is stage-local) and the OCP input
``ua = [v_l, delta, v_p, slack]`` (the model input plus the track-limit slack, >= 0).
With the car's speed loop in the model (``model.SpeedLoop``, ``cimpcc-line``) the augmented
state gets the car's speed ``v`` last (index ``XA_SPEED``; ``v_l`` is then its command), and
the velocity pull R3 weighs the speed the stage reaches, ``v_{k+1}``, instead of ``v_l,k``;
a per-stage parameter ``drag_k`` [m/s^2] (the reference lap's tyre drag at stage k) slows
it: ``v_{k+1} = F(...)_v - Ts drag_k``. With the car's servo in the model too
(``model.Servo``: a slow servo) the wheels' steering angle follows it (index ``XA_SERVO``;
``delta`` is then the servo's target).

Constraints, in order: gap 0, the initial-state equality, path constraints of stage 0, then
gap k and path constraints of stage k for k = 1..N-1. The path constraints keep the NEXT
predicted position inside the track, softened by the slack of that stage:
``-(w_left - margin) - slack <= e_con(F(xa_k, ua_k)) <= (w_right - margin) + slack``.
The lifted layout (``build_problem(lifted=True)``, ``cimpcc-line``'s option) keeps them on
the stage's own state ``xa_k`` instead (k = 1..N-1, and ``F(xa_{N-1}, ua_{N-1})`` at the last
stage): the same problem once the gaps are closed, with the model's second derivatives in
each stage once.

The reference path is an argument of the builder (``reference.ReferencePath``): the track's
centreline (the paper's CiMPCC and MPCC) or the minimum-time line (``cimpcc-line``), each a
closed polyline with its own arc length ``s`` and its half-widths to the real boundaries,
embedded as a bspline lookup.

Every weight, the current state, beta and the per-stage velocity references ``v_low,k``,
``v_up,k`` are parameters, so one built (and compiled) problem serves both paper methods and
every retuning; only N, Ts, the integrator, the model (L, its tyre slip), the margin and the
path are structural.
CiMPCC and MPCC set ``v_low,k = v_low`` and ``v_up,k = v_up`` at every stage (paper eq. 11);
``cimpcc-line`` sets ``beta_k = 1`` and ``v_up,k = v_low,k`` = the minimum-time profile's
speed at stage k's predicted progress.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import casadi as ca
import numpy as np

from services.planner.mpc.cost import speed_pull, stage_cost, terminal_cost
from services.planner.mpc.model import (
    NU,
    NX,
    SPEED,
    S,
    Servo,
    SlipModel,
    SpeedLoop,
    U,
    discretise,
    kinematic_bicycle,
)
from services.planner.reference import (
    R,
    ReferencePath,
    centreline_path,
    reference_lookup,
    track_errors,
)
from shared.config.planner import MethodWeights, PlannerSettings
from shared.track import Track


class XA(IntEnum):
    """Index of each element of the augmented OCP state."""

    X = S.X
    Y = S.Y
    PHI = S.PHI
    PROGRESS = S.PROGRESS
    V_L_PREV = NX + U.V_L
    DELTA_PREV = NX + U.DELTA
    V_P_PREV = NX + U.V_P


class UA(IntEnum):
    """Index of each element of the OCP input."""

    V_L = U.V_L
    DELTA = U.DELTA
    V_P = U.V_P
    SLACK = NU


NXA = len(XA)
NUA = len(UA)
#: Index of the car's speed in the augmented state of a problem with a speed loop (last).
XA_SPEED = NXA
#: Index of the wheels' steering angle in the augmented state of a problem with a servo.
XA_SERVO = NXA + 1
#: Elements of the velocity pair ``v = [v_l, v_p]`` (paper eq. 11).
NV = 2


@dataclass(frozen=True)
class ParamLayout:
    """Named slices of the parameter vector ``p``."""

    horizon: int
    nxa: int = NXA  #: size of the augmented state (NXA + 1 with a speed loop)

    def __post_init__(self) -> None:
        out, i = {}, 0
        for name, n in self.sizes.items():
            out[name] = slice(i, i + n)
            i += n
        object.__setattr__(self, "_slices", out)
        object.__setattr__(self, "_size", i)

    @property
    def sizes(self) -> dict[str, int]:
        """Size of each named parameter block."""
        return {
            "x0": self.nxa,
            "beta": self.horizon,
            "q": 2,  # contour, lag
            "gamma": 1,
            "r1": NU,
            "r2": NU,
            "u_ref": NU,
            "r3": NV,
            "v_up": NV * self.horizon,  # v_up,k = [v_l, v_p] of stage k, stage by stage
            "v_low": NV * self.horizon,
            "w_du0": 1,  # 1: weigh u_0 against the applied command, 0: paper (inside horizon)
            "slack_w": 2,  # linear, quadratic
            # speed loop only: the deceleration [m/s^2] beyond it at each stage (tyres' drag)
            **({"drag": self.horizon} if self.nxa > NXA else {}),
        }

    @property
    def slices(self) -> dict[str, slice]:
        """Slice of each named block in ``p``."""
        return self._slices  # type: ignore[attr-defined]

    @property
    def size(self) -> int:
        """Length of ``p``."""
        return self._size  # type: ignore[attr-defined]

    def split(self, p: ca.SX) -> dict[str, ca.SX]:
        """Symbolic blocks of ``p`` by name."""
        return {name: p[sl] for name, sl in self.slices.items()}

    @staticmethod
    def stage_pair(block: ca.SX, k: int) -> ca.SX:
        """Stage k's velocity pair ``[v_l, v_p]`` of a per-stage block (``v_up``, ``v_low``)."""
        return block[NV * k : NV * (k + 1)]

    def pack(
        self,
        x0: np.ndarray,
        beta: np.ndarray | float,
        weights: MethodWeights,
        w_du0: float,
        slack_w: tuple[float, float],
    ) -> np.ndarray:
        """The numeric parameter vector for one solve."""
        p = np.empty(self.size)
        sl = self.slices
        p[sl["x0"]] = x0
        p[sl["beta"]] = beta
        p[sl["q"]] = (weights.q_contour, weights.q_lag)
        p[sl["gamma"]] = weights.gamma
        p[sl["r1"]] = weights.r1_delta_u
        p[sl["r2"]] = weights.r2_input
        p[sl["u_ref"]] = weights.u_ref
        p[sl["r3"]] = weights.r3_velocity
        p[sl["v_up"]] = np.tile(weights.v_up_mps, self.horizon)
        p[sl["v_low"]] = np.tile(weights.v_low_mps, self.horizon)
        p[sl["w_du0"]] = w_du0
        p[sl["slack_w"]] = slack_w
        return p


@dataclass(frozen=True)
class OcpProblem:
    """A built problem: the NLP, its bounds and how to read its solution.

    Attributes:
        nlp: ``{"x": w, "p": p, "f": cost, "g": constraints}`` (SX).
        lbg, ubg: (ng,) constraint bounds.
        lbw, ubw: (nw,) variable bounds (input boxes, slack >= 0; states free).
        equality: (ng,) True for equality rows (fatrop's ``equality`` option).
        layout: the parameter layout.
        horizon: N.
        dt_s: Ts [s].
        step: discrete model step ``F(x[4], u[3]) -> x[4]``.
        dynamics: the continuous model ``f(x[4], u[3]) -> xdot[4]`` it discretises.
        errors: ``errors(x[4]) -> [e_con, e_lag]`` against the reference.
        signature: text that identifies the structure (for the compile cache key).
        reference: the path the problem contours (its progress ``s`` is the state's).
        nxa: size of the augmented state (``NXA``, ``NXA + 1`` with the car's speed,
            ``NXA + 2`` with its servo too).
        model_index: where the model's state (4, 5 or 6) sits in the augmented state.
    """

    nlp: dict
    lbg: np.ndarray
    ubg: np.ndarray
    lbw: np.ndarray
    ubw: np.ndarray
    equality: list[bool]
    layout: ParamLayout
    horizon: int
    dt_s: float
    step: ca.Function
    dynamics: ca.Function
    errors: ca.Function
    signature: str
    reference: ReferencePath
    nxa: int = NXA
    model_index: tuple[int, ...] = tuple(range(NX))

    @property
    def has_speed(self) -> bool:
        """Whether the model holds the car's speed (a speed loop, ``XA_SPEED``)."""
        return self.nxa > NXA

    @property
    def has_servo(self) -> bool:
        """Whether the model holds the wheels' steering angle (a servo, ``XA_SERVO``)."""
        return self.nxa > XA_SERVO

    def state_index(self, k: int) -> slice:
        """Slice of xa_k in w."""
        i = k * (self.nxa + NUA)
        return slice(i, i + self.nxa)

    def input_index(self, k: int) -> slice:
        """Slice of ua_k in w."""
        i = k * (self.nxa + NUA) + self.nxa
        return slice(i, i + NUA)

    def unpack(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(states (N+1, nxa), inputs (N, 4)) from a decision vector (copies)."""
        w = np.asarray(w, dtype=float).reshape(-1)
        n = self.horizon * (self.nxa + NUA)
        stages = w[:n].reshape(self.horizon, self.nxa + NUA)
        xs = np.vstack([stages[:, : self.nxa], w[n:][None, :]])
        return xs, stages[:, self.nxa :].copy()

    def pack(self, xs: np.ndarray, us: np.ndarray) -> np.ndarray:
        """Decision vector from (states (N+1, nxa), inputs (N, 4))."""
        stages = np.hstack([xs[: self.horizon], us])
        return np.concatenate([stages.ravel(), xs[self.horizon]])


def build_problem(
    reference: Track | ReferencePath,
    settings: PlannerSettings,
    slip: SlipModel | None = None,
    speed_loop: SpeedLoop | None = None,
    speed_cap_mps: float | None = None,
    lifted: bool = False,
    servo: Servo | None = None,
) -> OcpProblem:
    """Build the CiMPCC/MPCC NLP on a reference path with the structure fixed by `settings`.

    Args:
        reference: the path to contour (embedded as a bspline): a ``ReferencePath``, or a
            track, whose centreline it then is.
        settings: planner settings (N, Ts, integrator, L, margin, bounds).
        slip: the model's steady-state tyre slip (``model.SlipModel``, with its own L);
            None: the paper's kinematic bicycle with ``settings.wheelbase_m``.
        speed_loop: the car's speed loop (``model.SpeedLoop``): the car's speed becomes a
            state (``XA_SPEED``) and ``v_l`` its command; None: ``v_l`` is the speed (paper).
        speed_cap_mps: with `speed_loop`, the car's planned speed at stages 1..N is at most
            this [m/s] (a bound; stage 0 is the measured state); None: no cap.
        lifted: keep stage k's track limits (and, with `speed_loop`, the velocity pull on
            the speed it reaches) on the state variable ``xa_k`` itself (k = 1..N-1; stage
            N-1 keeps ``F(xa_{N-1}, ua_{N-1})``'s, the speed of xa_N is pulled in the
            terminal cost) instead of on the prediction ``F(xa_{k-1}, ua_{k-1})``: the same
            problem once the gaps are closed, but the model's second derivatives enter each
            stage once instead of three times (the solver's Hessian is half the size). The
            track-limit slack of stage 0 is then unused (bounded to 0). False: the paper's
            layout (the module docstring).
        servo: with `speed_loop`, the car's servo (``model.Servo``): the wheels' angle
            becomes a state (``XA_SERVO``) and ``delta`` the servo's target; None: none.
    """
    if servo is not None and speed_loop is None:
        raise ValueError("a servo state needs the speed loop's state before it")
    path = reference if isinstance(reference, ReferencePath) else centreline_path(reference)
    N = settings.horizon_steps
    f = kinematic_bicycle(settings.wheelbase_m, slip, speed_loop, servo)
    F = discretise(f, settings.dt_s, settings.integrator)
    ref = reference_lookup(path.path)
    speed = speed_loop is not None
    nxa = NXA + speed + (servo is not None)
    #: the model's state inside the augmented one
    model_index = tuple(range(NX)) + ((XA_SPEED,) if speed else ()) + (
        (XA_SERVO,) if servo is not None else ()
    )
    layout = ParamLayout(N, nxa)
    p = ca.SX.sym("p", layout.size)
    par = layout.split(p)
    margin = settings.track_margin_m

    xs = [ca.SX.sym(f"x{k}", nxa) for k in range(N + 1)]
    us = [ca.SX.sym(f"u{k}", NUA) for k in range(N)]
    w_parts, g, lbg, ubg, equality = [], [], [], [], []
    cost = 0
    for k in range(N):
        xk, uk = xs[k], us[k]
        w_parts += [xk, uk]
        zeta = ca.vertcat(*[xk[i] for i in model_index])
        u_model = uk[:NU]
        zeta_next = F(zeta, u_model)
        if speed:  # the known drag of stage k slows the car over the step
            zeta_next[SPEED] -= settings.dt_s * par["drag"][k]
            gap = xs[k + 1] - ca.vertcat(
                zeta_next[:NX], u_model, zeta_next[SPEED : SPEED + 1 + (servo is not None)]
            )
        else:
            gap = xs[k + 1] - ca.vertcat(zeta_next, u_model)
        g.append(gap)
        lbg += [0.0] * nxa
        ubg += [0.0] * nxa
        equality += [True] * nxa
        if k == 0:
            g.append(xk - par["x0"])
            lbg += [0.0] * nxa
            ubg += [0.0] * nxa
            equality += [True] * nxa
        # path constraint: the next position inside the (pulled-in) boundaries, soft;
        # lifted: this stage's own position (k >= 1), and the next one's at the last stage
        slack = uk[UA.SLACK]
        positions = (
            [zeta_next]
            if not lifted
            else ([xk] if k > 0 else []) + ([zeta_next] if k == N - 1 else [])
        )
        for zeta_c in positions:
            ref_c = ref(zeta_c[S.PROGRESS])
            e_con_c, _ = track_errors(ref_c, zeta_c[S.X], zeta_c[S.Y])
            g.append(
                ca.vertcat(
                    e_con_c + (ref_c[R.W_LEFT] - margin) + slack,
                    (ref_c[R.W_RIGHT] - margin) - e_con_c + slack,
                )
            )
            lbg += [0.0, 0.0]
            ubg += [np.inf, np.inf]
            equality += [False, False]
        e_con, e_lag = track_errors(ref(xk[XA.PROGRESS]), xk[XA.X], xk[XA.Y])
        # the speed the velocity pull weighs: the one this stage reaches (lifted: the
        # previous stage's pull on this stage's speed; the last one's in the terminal cost)
        v_pull = None
        if speed:
            v_pull = zeta_next[SPEED] if not lifted else xk[XA_SPEED]
        stage_refs = k if not lifted or not speed else k - 1
        cost += stage_cost(
            e_con=e_con,
            e_lag=e_lag,
            u=uk[:NU],
            u_prev=xk[XA.V_L_PREV : XA.V_P_PREV + 1],
            slack=slack,
            beta=par["beta"][k],
            v_low=layout.stage_pair(par["v_low"], k),
            v_up=layout.stage_pair(par["v_up"], k),
            par=par,
            dt_s=settings.dt_s,
            first_stage=(k == 0),
            v_l=v_pull,
            v_pull_refs=(
                None
                if stage_refs == k
                else False
                if stage_refs < 0
                else _pull_refs(par, layout, stage_refs)
            ),
        )
    w_parts.append(xs[N])
    e_con_n, e_lag_n = track_errors(ref(xs[N][XA.PROGRESS]), xs[N][XA.X], xs[N][XA.Y])
    cost += terminal_cost(e_con_n, e_lag_n, par)
    if lifted and speed:  # the last stage's pull on the speed it reaches
        beta_l, v_low_l, v_up_l = _pull_refs(par, layout, N - 1)
        cost += speed_pull(xs[N][XA_SPEED], beta_l, v_low_l, v_up_l, par)

    lbw = np.full(N * (nxa + NUA) + nxa, -np.inf)
    ubw = np.full_like(lbw, np.inf)
    b = settings.bounds
    for k in range(N):
        i = k * (nxa + NUA) + nxa
        lbw[i + UA.V_L], ubw[i + UA.V_L] = b.v_l_mps
        lbw[i + UA.DELTA], ubw[i + UA.DELTA] = b.delta_rad
        lbw[i + UA.V_P], ubw[i + UA.V_P] = b.v_p_mps
        lbw[i + UA.SLACK] = 0.0
    if lifted:  # stage 0 constrains no position: its slack is unused
        ubw[nxa + UA.SLACK] = 0.0
    if speed and speed_cap_mps is not None:
        for k in range(1, N + 1):
            ubw[k * (nxa + NUA) + XA_SPEED] = speed_cap_mps

    zeta = ca.SX.sym("zeta", NX)
    e_c, e_l = track_errors(ref(zeta[S.PROGRESS]), zeta[S.X], zeta[S.Y])
    errors = ca.Function("errors", [zeta], [ca.vertcat(e_c, e_l)])
    signature = "|".join(
        [
            "cimpcc-ocp-v2",  # v2: per-stage v_up/v_low, the path a builder argument
            f"path={path.kind}",
            f"N={N}",
            f"dt={settings.dt_s!r}",
            f"int={settings.integrator}",
            f"L={settings.wheelbase_m!r}" if slip is None else f"slip={slip!r}",
            f"margin={margin!r}",
            f"bounds={b.model_dump_json()}",
            f"track={track_fingerprint(path.path)}",
        ]
        + ([f"speed_loop={speed_loop!r},drag-param,cap={speed_cap_mps!r}"] if speed else [])
        + ([f"servo={servo!r}"] if servo is not None else [])
        + (["lifted"] if lifted else [])
    )
    return OcpProblem(
        nlp={"x": ca.vertcat(*w_parts), "p": p, "f": cost, "g": ca.vertcat(*g)},
        lbg=np.asarray(lbg),
        ubg=np.asarray(ubg),
        lbw=lbw,
        ubw=ubw,
        equality=equality,
        layout=layout,
        horizon=N,
        dt_s=settings.dt_s,
        step=F,
        dynamics=f,
        errors=errors,
        signature=signature,
        reference=path,
        nxa=nxa,
        model_index=model_index,
    )


def _pull_refs(par: dict, layout: ParamLayout, k: int) -> tuple[ca.SX, ca.SX, ca.SX]:
    """(beta_k, v_low,k, v_up,k) of stage k's velocity pull."""
    return (
        par["beta"][k],
        layout.stage_pair(par["v_low"], k),
        layout.stage_pair(par["v_up"], k),
    )


def track_fingerprint(track: Track) -> str:
    """A short hash of a track's or path's geometry: points and widths (for cache keys)."""
    import hashlib

    h = hashlib.sha256()
    for arr in (track.xy, track.w_right_m, track.w_left_m):
        h.update(np.ascontiguousarray(arr, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]
