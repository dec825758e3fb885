"""Figures and convergence orders from the CSVs of ``run.py`` (analysis only, no simulation).

    PYTHONPATH=. python experiments/validation_ns/plot.py

Writes results/taylor_green.png, results/poiseuille.png and results/orders.csv
(observed order p = log(e_coarse / e_fine) / log 2 between successive refinements).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import xarray as xr  # noqa: E402

RES = Path(__file__).resolve().parent / "results"


def orders(x, e):
    x, e = np.asarray(x, float), np.asarray(e, float)
    return np.log(np.abs(e[:-1]) / np.abs(e[1:])) / np.log(x[:-1] / x[1:])


def main():
    tg = pd.read_csv(RES / "taylor_green.csv")
    po = pd.read_csv(RES / "poiseuille.csv")
    rows = []
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for scheme, grp in tg.groupby("scheme"):
        hd = grp[grp.study == "h_and_dt"].sort_values("cells")
        h = 2 * np.pi / hd.cells.to_numpy()
        axes[0].loglog(h, np.abs(hd.rate_rel_error), "o-", label=f"{scheme}: decay rate")
        axes[0].loglog(h, hd.linf_rel_error, "s--", label=f"{scheme}: L-inf u")
        for metric, errors in (("rate", hd.rate_rel_error), ("linf", hd.linf_rel_error)):
            for n, p in zip(hd.cells.to_numpy()[1:], orders(h, errors), strict=True):
                rows.append(
                    dict(
                        study="taylor_green h+dt (CFL 0.5)",
                        scheme=scheme,
                        cells=n,
                        metric=metric,
                        order=p,
                    )
                )
        dd = grp[grp.study == "dt_at_64"].sort_values("dt", ascending=False)
        axes[1].loglog(dd.dt, np.abs(dd.rate_rel_error), "o-", label=scheme)
        for dt, p in zip(dd.dt.to_numpy()[1:], orders(dd.dt, dd.rate_rel_error), strict=True):
            rows.append(
                dict(
                    study="taylor_green dt at 64 cells",
                    scheme=scheme,
                    cells=64,
                    dt=dt,
                    metric="rate",
                    order=p,
                )
            )
    axes[0].set(xlabel="h (m)", ylabel="relative error", title="Taylor-Green, CFL 0.5")
    axes[1].set(xlabel="dt (s)", ylabel="|rate error| (relative)", title="Taylor-Green, 64 cells")
    for ax in axes:
        ax.legend(fontsize=7)
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(RES / "taylor_green.png", dpi=120)

    po = po.sort_values("cells")
    for n, p in zip(po.cells.to_numpy()[1:], orders(1 / po.cells, po.linf_rel_error), strict=True):
        rows.append(dict(study="poiseuille", scheme="-", cells=n, metric="linf", order=p))
    ds = xr.open_dataset(RES / "poiseuille.nc")
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for n in po.cells:
        axes[0].plot(ds[f"u_{n}"], ds[f"y_{n}"], ".-", label=f"{n} cells")
    n = int(po.cells.max())
    axes[0].plot(ds[f"u_exact_{n}"], ds[f"y_{n}"], "k-", lw=0.8, label="analytic")
    axes[0].set(xlabel="u (m/s)", ylabel="y (m)", title="Poiseuille, steady")
    axes[0].legend(fontsize=7)
    axes[1].loglog(1 / po.cells, po.linf_rel_error, "o-")
    axes[1].set(xlabel="h (m)", ylabel="max |u - u_exact| / u_max", title="Poiseuille error")
    axes[1].grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(RES / "poiseuille.png", dpi=120)
    out = pd.DataFrame(rows)
    out.to_csv(RES / "orders.csv", index=False)
    print(out.to_string(index=False))


if __name__ == "__main__":
    main()
