"""What the plot scripts plot_accuracy.py and plot_sweep.py share: matplotlib's pyplot without a display (Agg), and
a CSV cell read as a number. Installed beside them (apps/dvisim/CMakeLists.txt)."""
import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402,F401  (re-exported)


def fl(x):
    """A CSV cell as a finite float; None when it is empty, not a number, infinite or NaN."""
    try:
        v = float(x)
        return v if math.isfinite(v) else None
    except (TypeError, ValueError):
        return None
