"""The fit report: markdown tables and a figure like the paper's Fig. 3.

:func:`diagnostics` compares the data with the fitted model per distance bin (rows,
observed and predicted fraction of -1, observed median d against the model's median and
90 % band from simulating every row's geometry), and computes randomised PIT values
(u_i = P(d < d_i) + V P(d = d_i), V uniform; :func:`diagnostics.pit_values`): if the
model is right they are uniform on [0, 1] whatever the geometry. The report also shows the
fit's goodness-of-fit test per distance bin (:mod:`.diagnostics`, ``result.goodness_of_fit``). :func:`write_report` writes ``report.md`` and, when
matplotlib (the ``plot`` extra) is installed, ``fit.png``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .diagnostics import ALPHA, UNEXPECTED_CENSORED, GoodnessOfFit, pit_values
from .eiv import model_rows
from .result import FitResult
from .likelihood import Likelihood, simulate
from .table import Table

PNG_NAME = "fit.png"
MD_NAME = "report.md"


class PlotUnavailable(RuntimeError):
    """matplotlib is not installed."""


@dataclass
class Diagnostics:
    r: NDArray[np.float64]  # true distance per row (m)
    d: NDArray[np.int64]  # observed (cm, -1)
    edges: NDArray[np.float64]  # distance bins (m)
    n: NDArray[np.int64]
    obs_cens: NDArray[np.float64]
    model_cens: NDArray[np.float64]
    obs_median: NDArray[np.float64]  # m, nan without detections
    model_q: NDArray[np.float64]  # (bins, 3): 5 %, 50 %, 95 % of detected d (m)
    inside: NDArray[np.float64]  # fraction of detected rows inside the model's 90 % band
    mean_loglik: NDArray[np.float64]
    pit: NDArray[np.float64]
    ks: float
    replicates: int

    @property
    def centers(self) -> NDArray[np.float64]:
        return 0.5 * (self.edges[1:] + self.edges[:-1])


def diagnostics(table: Table, result: FitResult, seed: int = 0) -> Diagnostics:
    params = result.params
    rows = model_rows(table, params)
    like = Likelihood(rows)
    like.choose_regimes(params)
    spread = wide = None
    if rows.moments is not None:
        zero = np.zeros(rows.k.shape[0])
        usual, outlier = params.outlier_components()
        s_xy, _s3, _l3, shift = like.pose_spread(usual, zero, zero)
        spread = (shift, np.broadcast_to(s_xy, zero.shape))
        if params.gps_outlier > 0.0:  # heavy-tailed GPS error: a row's draw from the wide component
            s_xy, _s3, _l3, shift = like.pose_spread(outlier, zero, zero)
            wide = (shift, np.broadcast_to(s_xy, zero.shape))
    r = np.exp(rows.geo.log_r)
    d = rows.k
    top = float(np.max(r))
    step = max(0.5, float(np.ceil(top / 30.0 * 2.0) / 2.0))
    edges = np.arange(0.0, top + step, step)
    which = np.clip(np.digitize(r, edges) - 1, 0, len(edges) - 2)
    nb = len(edges) - 1

    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0xD1A6,)))
    reps = int(min(200, max(4, 400000 // max(len(d), 1))))
    geo = like.geometry(params)  # (with a mounting bias, the receiver's own attitude)

    def draw(spread):
        if wide is not None:
            pick = rng.random(zero.shape[0]) < params.gps_outlier
            spread = tuple(np.where(pick, w, u) for u, w in zip(spread, wide))
        return simulate(geo, params, rng, spread)

    sims = np.stack([draw(spread) for _ in range(reps)], axis=1)  # (n, reps)
    logp = like.logp(params)
    pit, p_cens = pit_values(like, params, rng.random(len(d)))
    ks = _ks_uniform(pit)

    n = np.bincount(which, minlength=nb)
    det = d != -1
    obs_cens = _ratio(np.bincount(which, weights=~det, minlength=nb), n)
    model_cens = _ratio(np.bincount(which, weights=p_cens, minlength=nb), n)
    mean_ll = _ratio(np.bincount(which, weights=logp, minlength=nb), n)
    obs_median = np.full(nb, np.nan)
    model_q = np.full((nb, 3), np.nan)
    inside = np.full(nb, np.nan)
    for b in range(nb):
        sel = which == b
        if not sel.any():
            continue
        obs = d[sel & det] / 100.0
        if obs.size:
            obs_median[b] = float(np.median(obs))
        s = sims[sel].ravel()
        s = s[s != -1] / 100.0
        if s.size >= 20:
            model_q[b] = np.quantile(s, [0.05, 0.5, 0.95])
            if obs.size:
                inside[b] = float(np.mean((obs >= model_q[b, 0]) & (obs <= model_q[b, 2])))
    return Diagnostics(r, d, edges, n, obs_cens, model_cens, obs_median, model_q, inside, mean_ll, pit, ks, reps)


def _ratio(a, b):
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(b > 0, a / np.maximum(b, 1), np.nan)


def _ks_uniform(u: NDArray[np.float64]) -> float:
    """Kolmogorov-Smirnov distance of u from the uniform distribution on [0, 1]."""
    if u.size == 0:
        return float("nan")
    s = np.sort(u)
    i = np.arange(1, s.size + 1)
    return float(max(np.max(i / s.size - s), np.max(s - (i - 1) / s.size)))


def _fmt(x: float, digits: int = 3) -> str:
    return "" if x is None or not math.isfinite(x) else f"{x:.{digits}g}"


def markdown(result: FitResult, diag: Diagnostics, png: str | None) -> str:
    p = result.params
    out = [f"# Receiver model fit: {result.source}", ""]
    status = "converged" if result.converged else f"**did not converge**: {result.message}"
    out += [
        f"{result.n_rows} rows ({result.n_censored} with d = -1, {result.n_rows - result.n_used - result.n_pose_dropped} "
        f"skipped at distance 0, {result.n_pose_dropped} closer than the pose error allows); fit {status} in {result.iterations} iterations, {result.seconds:.2f} s; "
        f"log-likelihood {result.log_likelihood:.2f}.",
        "",
        "| parameter | estimate | standard error | 95 % interval |",
        "|---|---|---|---|",
    ]
    if not result.separable:
        out[-2:-2] = [
            "**r_en is not determined: pose error and EMI noise cannot be told apart with these rows** "
            "(see the notes).",
            "",
        ]
    for name in ("kappa_eq", "r_en", "r_outer", "pose_sigma", "time_offset", "gps_sigma", "attitude_sigma", "q"):
        if name == "q":
            if "q" in result.free:
                est, se = result.estimate["q"], result.se.get("q", float("nan"))
                out.append(f"| q_y / q_x | {est:.4g} | {_fmt(se)} | {_ci(est, se, True)} |")
            out.append(f"| q (fixed max 1) | {', '.join(f'{v:.4g}' for v in p.q)} | | |")
            continue
        val = getattr(p, name)
        if name == "attitude_sigma":  # shown in degrees
            val = math.degrees(val)
            name = "attitude_sigma (deg)"
            if "attitude_sigma" in result.free:
                se = math.degrees(result.se.get("attitude_sigma", float("nan")))
                out.append(f"| {name} | {val:.4g} | {_fmt(se)} | {_ci(val, se, True)} |")
                continue
        if name in result.free:
            se = result.se.get(name, float("nan"))
            out.append(f"| {name} | {val:.6g} | {_fmt(se)} | {_ci(val, se, name != 'time_offset')} |")
        else:
            out.append(f"| {name} (fixed) | {val:.6g} | | |")
    out += ["", "kappa_eq is for a transmitter moment s = 1: only kappa_eq / s can be estimated from d."]
    if result.hac_lag == result.hac_lag:
        out += [
            "Standard errors: sandwich covariance with a time-block (Newey-West) meat, bandwidth "
            f"{result.hac_lag:.0f} s, robust to pose errors correlated in time, scaled so that +-1.96 s.e. "
            "is a 95 % interval at that bandwidth (fixed-b).",
        ]
    if "gps_sigma" in result.free or p.gps_sigma > 0:
        out += [f"GPS error {p.gps_sigma:.3g} m horizontal, {p.gps_ratio * p.gps_sigma:.3g} m vertical (1 sigma)."]
    out += [""]
    if result.notes:
        out += ["Notes:", ""] + [f"* {note}" for note in result.notes] + [""]
    naive = result.naive
    out += [
        "Naive least squares on the detected rows only (ignores -1 rows, rounding and the noise "
        f"distribution): kappa_eq {_fmt(naive['kappa_eq'], 6)}, r_en {_fmt(naive['r_en'], 4)} m.",
        "",
    ]
    if png:
        out += [f"![d versus true distance]({png})", ""]
    inside_all = _weighted(diag.inside, diag.n)
    out += [
        "## Match per distance bin",
        "",
        "Model columns come from simulating every row's geometry "
        f"{diag.replicates} times with the fitted parameters; the 90 % band holds 90 % of the "
        "simulated detections in the bin.",
        "",
        "| distance (m) | rows | -1 observed | -1 model | median d observed (m) | median d model (m) "
        "| model 90 % band (m) | detected inside band | mean log-lik |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for b in range(len(diag.n)):
        if diag.n[b] == 0:
            continue
        q = diag.model_q[b]
        band = f"{q[0]:.2f} - {q[2]:.2f}" if math.isfinite(q[0]) else ""
        out.append(
            f"| {diag.edges[b]:.1f} - {diag.edges[b + 1]:.1f} | {diag.n[b]} | {diag.obs_cens[b]:.3f} | "
            f"{diag.model_cens[b]:.3f} | {_fmt(diag.obs_median[b], 4)} | {_fmt(q[1], 4)} | {band} | "
            f"{_fmt(diag.inside[b], 3)} | {diag.mean_loglik[b]:.2f} |"
        )
    hist = np.histogram(diag.pit, bins=10, range=(0, 1))[0] / max(diag.pit.size, 1)
    ks_crit = 1.358 / math.sqrt(max(diag.pit.size, 1))
    out += [
        "",
        "## Residuals",
        "",
        f"* Detected rows inside their bin's 90 % band: {_fmt(inside_all, 3)} (0.9 expected).",
        f"* Randomised PIT values: Kolmogorov-Smirnov distance from uniform {diag.ks:.4f} "
        f"(5 % critical value {ks_crit:.4f} for independent rows: with pose error correlated in time it is too "
        "small, see 'Goodness of fit' below); deciles "
        + ", ".join(f"{h:.3f}" for h in hist)
        + " (0.1 each expected).",
        f"* Observed -1 fraction {np.mean(diag.d == -1):.4f}; model {_weighted(diag.model_cens, diag.n):.4f}.",
        "",
    ]
    if result.goodness_of_fit is not None:
        out += gof_markdown(result.goodness_of_fit)
    out += [
        "How to read this: docs/calibration.md, section 'Reading the report'.",
        "",
    ]
    return "\n".join(out)


def gof_markdown(gof: GoodnessOfFit) -> list[str]:
    """The goodness-of-fit test's section of report.md."""
    verdict = "no misfit found" if gof.fits else "**the model does not fit** (see the notes)"
    out = [
        "## Goodness of fit",
        "",
        f"Randomised PIT residuals by distance on {gof.rows} rows, variances from time blocks of "
        f"{gof.lag_seconds:.0f} s (0: rows independent): p = {gof.p_value:.2g} ({gof.tests} statistics, "
        f"Bonferroni; misfit below {ALPHA:g}): {verdict}. -1 rows the model gives less than "
        f"{100 * UNEXPECTED_CENSORED:g} %: {gof.unexpected_censored} ({gof.expected_unexpected:.2g} expected).",
        "",
        "| distance (m) | rows | mean PIT score (0) | variance (1) | in the outer 1 % | unexpected -1 "
        "| shift z | scatter z | tails z |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for b in gof.bins:
        span = f"{b.lo:g} - {b.hi:g}" if math.isfinite(b.hi) else f"{b.lo:g} -"
        out.append(
            f"| {span} | {b.rows} | {b.mean_z:+.3f} | {b.var_z:.3f} | {100 * b.tail_fraction:.1f} % | "
            f"{b.unexpected_censored} | {b.z['shift']:+.2f} | {b.z['scatter']:+.2f} | {b.z['tails']:+.2f} |"
        )
    return out + [""]


def _ci(est: float, se: float, log: bool) -> str:
    if not (se == se and est == est) or se is None:
        return ""
    if log and est > 0:
        f = math.exp(1.96 * se / est)
        return f"{est / f:.5g} - {est * f:.5g}"
    return f"{est - 1.96 * se:.5g} - {est + 1.96 * se:.5g}"


def _weighted(values, weights) -> float:
    ok = np.isfinite(values) & (weights > 0)
    return float(np.sum(values[ok] * weights[ok]) / np.sum(weights[ok])) if ok.any() else float("nan")


def plot(result: FitResult, diag: Diagnostics, path: Path) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise PlotUnavailable("matplotlib is not installed (pip install 'arva-bench[plot]')") from None
    fig, axes = plt.subplots(3, 1, figsize=(8, 10), height_ratios=[3, 1.3, 1.3])
    ax = axes[0]
    det = diag.d != -1
    c = diag.centers
    ok = np.isfinite(diag.model_q[:, 1])
    ax.fill_between(c[ok], diag.model_q[ok, 0], diag.model_q[ok, 2], color="tab:orange", alpha=0.25, label="model 90 % band")
    ax.plot(c[ok], diag.model_q[ok, 1], color="tab:orange", lw=2, label="model median")
    ax.scatter(diag.r[det], diag.d[det] / 100.0, s=4, color="tab:blue", alpha=0.5, label="d (detected)")
    ax.scatter(diag.r[~det], np.full((~det).sum(), -1.0), s=4, color="tab:red", alpha=0.5, label="d = -1")
    top = float(np.max(diag.r))
    ax.plot([0, top], [0, top], color="grey", lw=0.8, ls=":", label="d = true distance")
    ax.set_xlabel("true distance |p| (m)")
    ax.set_ylabel("d (m)")
    p = result.params
    ax.set_title(f"{result.source}: kappa_eq = {p.kappa_eq:.5g}, r_en = {p.r_en:.4g} m")
    ax.legend(loc="upper left", fontsize=8, markerscale=3)
    ax.grid(alpha=0.3)
    ax = axes[1]
    has = diag.n > 0
    lo, hi = _wilson(diag.obs_cens[has] * diag.n[has], diag.n[has])
    yerr = np.maximum([diag.obs_cens[has] - lo, hi - diag.obs_cens[has]], 0.0)
    ax.errorbar(c[has], diag.obs_cens[has], yerr=yerr, fmt="o", ms=3, color="tab:red", label="observed (90 % interval)")
    ax.plot(c[has], diag.model_cens[has], color="black", lw=1.5, label="model")
    ax.set_xlabel("true distance |p| (m)")
    ax.set_ylabel("fraction of -1")
    ax.set_ylim(-0.03, 1.03)
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    ax = axes[2]
    ax.hist(diag.pit, bins=20, range=(0, 1), density=True, color="tab:blue", alpha=0.7)
    ax.axhline(1.0, color="black", lw=1)
    ax.set_xlabel(f"randomised PIT value (uniform if the model fits; KS distance {diag.ks:.3f})")
    ax.set_ylabel("density")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _wilson(k, n, z: float = 1.645):
    n = np.maximum(n, 1)
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return np.clip(centre - half, 0, 1), np.clip(centre + half, 0, 1)


def write_report(directory: str | Path, table: Table, result: FitResult, seed: int = 0) -> tuple[Path, Path | None, str | None]:
    """Write report.md (and fit.png when matplotlib is there). Returns (md, png, warning)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    diag = diagnostics(table, result, seed)
    png: Path | None = directory / PNG_NAME
    warning = None
    try:
        plot(result, diag, png)
    except PlotUnavailable as exc:
        png, warning = None, f"no figure: {exc}"
    md = directory / MD_NAME
    md.write_text(markdown(result, diag, PNG_NAME if png else None))
    return md, png, warning
