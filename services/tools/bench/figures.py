"""Moved to ``shared.evaluation.figures``; re-exported here so the bench's imports keep
working."""

from shared.evaluation.figures import (
    fig_curvature,
    fig_laps,
    fig_solve_time,
    fig_speed_vs_s,
    fig_trajectories,
    write_figures,
)

__all__ = [
    "fig_curvature",
    "fig_laps",
    "fig_solve_time",
    "fig_speed_vs_s",
    "fig_trajectories",
    "write_figures",
]
