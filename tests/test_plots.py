"""Figures: what they show, read back from the matplotlib objects (not from pixels)."""
import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hpcves import plots  # noqa: E402
from hpcves.regimes import OUTCOMES  # noqa: E402


def _row(regime, S, psi_bar, period=math.nan):
    return {"regime": regime, "shear_rate": S, "psi_bar": psi_bar, "period": period}


def test_every_outcome_has_its_own_marker_and_legend_entry():
    rows = [_row(regime, S, 0.1 * k) for k, regime in enumerate(OUTCOMES, 1) for S in (5.0, 20.0)]
    fig = plots.phase_diagram(rows, "shear_rate", "psi_bar")
    try:
        legend = fig.axes[0].get_legend()
        labels = [t.get_text() for t in legend.get_texts()]
        assert len(labels) == len(OUTCOMES) and all(label.endswith("(2)") for label in labels)
        assert any(label.startswith("model limit") for label in labels)
        assert "failed (2)" in labels and "undecided (2)" in labels
        styles = {(str(plots.REGIME_STYLE[r][0]), plots.REGIME_STYLE[r][1]) for r in OUTCOMES}
        assert len(styles) == len(OUTCOMES)                 # no two outcomes look alike
        for collection, regime in zip(fig.axes[0].collections, OUTCOMES):
            assert np.allclose(collection.get_offsets()[:, 1], rows[2 * OUTCOMES.index(regime)]["psi_bar"])
    finally:
        plt.close(fig)
