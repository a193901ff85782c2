"""The cost of CiMPCC and MPCC: J_MPCC (paper eq. 3) plus J_Ci (paper eq. 11).

Per stage k with model input ``u_k = [v_l, delta, v_p]`` and velocity pair ``v_k = [v_l, v_p]``:

    q_c e_con^2 + q_l e_lag^2                       contour and lag error (Q)
    - gamma v_p,k Ts                                progress reward
    + ||u_k - u_{k-1}||^2_R1                        input rate (stage 0: times w_du0)
    + ||u_k - u_ref||^2_R2                          input reference (MPCC's speed pull)
    + (1 - beta_k) ||v_k - v_low,k||^2_R3           CiMPCC: pull to safe speeds
    + beta_k ||v_k - v_up,k||^2_R3                  CiMPCC: pull to aggressive speeds
    + rho_1 slack_k + rho_2 slack_k^2               soft track limits

MPCC is R3 = 0; CiMPCC is R2 = diag(0, 10, 0) with R3 = diag(40, 40) (paper section IV)
and the same ``v_low``, ``v_up`` at every stage; ``cimpcc-line`` has beta_k = 1 and
``v_up,k`` = the minimum-time profile's speed at stage k.
All weights and references come from the parameter vector (see ``problem.ParamLayout``).
"""

from __future__ import annotations

import casadi as ca

from services.planner.mpc.model import U


def _quad(diff: ca.SX, weights: ca.SX) -> ca.SX:
    """``||diff||^2_diag(weights)``."""
    return ca.sum1(weights * diff**2)


def stage_cost(
    *,
    e_con: ca.SX,
    e_lag: ca.SX,
    u: ca.SX,
    u_prev: ca.SX,
    slack: ca.SX,
    beta: ca.SX,
    v_low: ca.SX,
    v_up: ca.SX,
    par: dict[str, ca.SX],
    dt_s: float,
    first_stage: bool,
    v_l: ca.SX | None = None,
    v_pull_refs: tuple[ca.SX, ca.SX, ca.SX] | bool | None = None,
) -> ca.SX:
    """Cost of one stage (see the module docstring).

    `beta`, `v_low`, `v_up` ([v_l, v_p] [m/s]) are the stage's; `par` holds the named
    parameter blocks of the weights. `v_l`: the speed the velocity pulls weigh in place of
    the input's ``v_l`` (a model with the car's speed loop: the speed the stage reaches).
    `v_pull_refs`: (beta, v_low, v_up) of the pull on `v_l` when they are another stage's
    (the lifted problem pulls stage k's own speed with stage k-1's references); False: no
    pull on `v_l` (a fixed speed: stage 0's); None: this stage's.
    """
    q = par["q"]
    cost = q[0] * e_con**2 + q[1] * e_lag**2
    cost -= par["gamma"] * u[U.V_P] * dt_s
    du = _quad(u - u_prev, par["r1"])
    cost += par["w_du0"] * du if first_stage else du
    cost += _quad(u - par["u_ref"], par["r2"])
    if v_pull_refs is None:
        v = ca.vertcat(u[U.V_L] if v_l is None else v_l, u[U.V_P])
        cost += (1 - beta) * _quad(v - v_low, par["r3"])
        cost += beta * _quad(v - v_up, par["r3"])
    else:  # the pulls on v_l and on v_p, each with its own stage's references
        r3 = par["r3"]
        cost += r3[1] * ((1 - beta) * (u[U.V_P] - v_low[1]) ** 2 + beta * (u[U.V_P] - v_up[1]) ** 2)
        if v_pull_refs is not False:
            assert v_l is not None and not isinstance(v_pull_refs, bool)
            cost += speed_pull(v_l, *v_pull_refs, par)
    cost += par["slack_w"][0] * slack + par["slack_w"][1] * slack**2
    return cost


def speed_pull(v: ca.SX, beta: ca.SX, v_low: ca.SX, v_up: ca.SX, par: dict[str, ca.SX]) -> ca.SX:
    """CiMPCC's velocity pull on the speed element alone: ``R3[0] ((1 - beta) (v -
    v_low[0])^2 + beta (v - v_up[0])^2)`` (`v_low`, `v_up`: the stage's [v_l, v_p] pair)."""
    r3 = par["r3"]
    return r3[0] * ((1 - beta) * (v - v_low[0]) ** 2 + beta * (v - v_up[0]) ** 2)


def terminal_cost(e_con: ca.SX, e_lag: ca.SX, par: dict[str, ca.SX]) -> ca.SX:
    """Contour and lag error of the last predicted state."""
    q = par["q"]
    return q[0] * e_con**2 + q[1] * e_lag**2
