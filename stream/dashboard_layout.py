"""The dashboard's layout: which panel shows which entities, and how each series is named and
coloured. Bands are two series of one entity, ``lower`` and ``upper``, in a light tint of their
centre line's colour (Rerun 0.41 draws lines and points, no filled areas)."""

from __future__ import annotations

import rerun.blueprint as rrb

#: The wall-clock timeline the viewer opens on; every entity also carries ``point``.
TIMELINE = "time"

ERROR_RGB = (200, 60, 40)
_ERROR_BAND = (240, 150, 130)
_EPI_BAND = (120, 120, 220)


def _bands(panel: str) -> dict[str, dict]:
    """The styles of a panel's two 90 % bands around its error line: predictive (aleatoric +
    epistemic) and epistemic only."""
    return {
        f"{panel}/{band}": {
            "names": [f"90 % {what}: lower", f"90 % {what}: upper"],
            "colors": [colour, colour],
        }
        for band, what, colour in (
            ("interval", "predictive", _ERROR_BAND),
            ("epistemic", "epistemic", _EPI_BAND),
        )
    }


#: Static styles (``rr.SeriesLines`` keyword arguments, or ``kind="points"`` for markers) by
#: entity path.
SERIES_STYLE: dict[str, dict] = {
    "points/error/measured": {
        "kind": "points",
        "names": ["measured"],
        "colors": [(60, 60, 60)],
        "marker_sizes": [1.5],
    },
    "points/error/predicted": {"names": ["predicted (lagging model)"], "colors": [ERROR_RGB]},
    **_bands("points/error"),
    "points/left/error": {"names": ["error left (lagging model)"], "colors": [ERROR_RGB]},
    **_bands("points/left"),
    "metrics/test_error/mean": {
        "names": ["held-out test mean (current model)"],
        "colors": [(20, 120, 60)],
        "widths": [2.5],
    },
    "metrics/test_error/max": {"names": ["held-out test max"], "colors": [(120, 190, 140)]},
    "metrics/batch_error/mean": {"names": ["new batch mean"], "colors": [(200, 150, 40)]},
    "metrics/uncertainty/aleatoric": {"names": ["aleatoric mean"], "colors": [(200, 120, 40)]},
    "metrics/uncertainty/epistemic": {"names": ["epistemic mean"], "colors": [(80, 80, 200)]},
    "metrics/uncertainty/epistemic_p90": {"names": ["epistemic p90"], "colors": [_EPI_BAND]},
    "coverage/interval_90": {
        "names": ["rolling coverage", "nominal 0.90"],
        "colors": [(20, 120, 60), (150, 150, 150)],
    },
    "metrics/model/version": {"names": ["model version"]},
    "metrics/memory/size": {"names": ["memory points"]},
    "metrics/quarantined": {"names": ["quarantined points"], "colors": [(200, 40, 40)]},
    "metrics/withheld": {"names": ["withheld updates"], "colors": [(120, 40, 160)]},
    "compensation/correction": {"names": ["predicted correction"]},
    "compensation/residual": {"names": ["solver residual"], "colors": [(200, 40, 40)]},
    "compensation/epistemic": {"names": ["epistemic std"], "colors": [(80, 80, 200)]},
    "compensation/trusted": {"names": ["trusted (1) / not (0)"], "colors": [(150, 150, 150)]},
}


def _series(name: str, *contents: str) -> rrb.TimeSeriesView:
    """A plot of ``contents`` over the whole timeline (it would scroll with the time cursor)."""
    everything = rrb.TimeRange(
        start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite()
    )
    return rrb.TimeSeriesView(
        origin="/",
        contents=list(contents),
        name=name,
        axis_x=rrb.TimeAxis(link="Independent", view_range=everything),
    )


def blueprint(reach_m: float = 3.0) -> rrb.Blueprint:
    """Per-point errors and learning curves on the left, the 3-D cell on the right (the eye
    placed for a robot of ``reach_m``); the time panel on the wall-clock timeline, following
    the newest data."""
    r = reach_m
    eye = rrb.EyeControls3D(
        kind="Orbital",
        position=(1.3 * r, -1.5 * r, 1.0 * r),
        look_target=(0.25 * r, 0.0, 0.3 * r),
        eye_up=(0.0, 0.0, 1.0),
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Horizontal(
                    _series(
                        "Position error per point: measured, and predicted by the lagging "
                        "model with 90 % bands (mm)",
                        "points/error/**",
                    ),
                    _series(
                        "Error left per point, scored by the model before it learned the "
                        "point (mm); held-out test error of the current model",
                        "points/left/**",
                        "metrics/test_error/mean",
                    ),
                ),
                rrb.Horizontal(
                    _series(
                        "Held-out test error, newest model (mm)",
                        "metrics/test_error/**",
                        "metrics/batch_error/**",
                    ),
                    _series("Uncertainty on the test points (mm, std)", "metrics/uncertainty/**"),
                    _series("Coverage of the 90 % interval, rolling", "coverage/**"),
                ),
                rrb.Horizontal(
                    _series("Joints (deg)", "inputs/joints"),
                    _series("Temperatures (°C)", "inputs/temperatures"),
                    _series("Dropped messages by stage and reason (count)", "drops/**"),
                ),
                rrb.Horizontal(
                    _series(
                        "Model version, memory, quarantined points, withheld updates",
                        "metrics/model/**",
                        "metrics/memory/size",
                        "metrics/quarantined",
                        "metrics/withheld",
                    ),
                    rrb.BarChartView(origin="/metrics/memory/age", name="Memory by batch age"),
                    _series("Compensation answers (mm)", "compensation/**"),
                ),
                row_shares=[3, 2, 2, 2],
            ),
            rrb.Spatial3DView(
                origin="/world", name="Cell (base frame, m): points by error left", eye_controls=eye
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline=TIMELINE, state="collapsed", play_state="following"),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    )
