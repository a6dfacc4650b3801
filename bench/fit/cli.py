"""``arva-bench fit INPUT``: calibrate the receiver model from a logged campaign.

INPUT is a CSV with the normative columns (BRIEF 7; ``-`` reads stdin) or a session
directory (through the session export). Prints a summary (or ``--json``: one JSON
object), optionally writes a report (``--report DIR``: report.md + fit.png) and the fitted
``[model]`` table into a scene (``--write-scene FILE``). Exit status: 0 fitted; 1 the fit
did not converge (said on stderr; ``--json`` still prints, with ``"converged": false``);
2 unusable input or arguments (one line ``arva-bench: fit: <reason>``).

This module imports only argparse at load time: the numerics load when the command runs.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from emulator.cli_types import output_dir, output_file, probe_creatable_dir, probe_writable, real, seed
from emulator.progress import progress

from .grades import GPS_GRADE_RATIO, GPS_GRADES, IMU_GRADES

OPTIONAL_FREE = ("q", "r_outer", "time_offset", "height_offset", "dropout", "gps_outlier", "mounting")
#: ``--fit`` names that free several parameters: the share of GPS outliers with their
#: width; the mounting bias's pitch and roll (docs/calibration.md section 2).
ALIASES = {"gps_outlier": ("gps_outlier", "gps_outlier_scale"), "mounting": ("mount_pitch", "mount_roll")}


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "fit",
        help="fit kappa_eq and r_en (the receiver model) to a logged campaign",
        description=(
            "Fit the receiver model (kappa_eq, the noise-equivalent distance r_en and the pose "
            "error) to a campaign by maximum likelihood, with standard errors. INPUT is a CSV "
            "with the normative columns (t, seq, id, d, delta, rx_x .. rx_qz, tx_x .. tx_qz), "
            "'-' for stdin, or a session directory."
        ),
        epilog="Method, assumptions and how to read the report: docs/calibration.md.",
    )
    p.add_argument("input", metavar="INPUT", help="CSV file, '-' (stdin) or session directory")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the summary")
    p.add_argument("--report", metavar="DIR", type=output_dir, help="write DIR/report.md and DIR/fit.png")
    p.add_argument(
        "--write-scene", metavar="FILE", type=output_file(), help="write the fitted [model] table into scene FILE (created if missing)"
    )
    p.add_argument(
        "--fit",
        metavar="NAMES",
        action="append",
        default=[],
        help=f"also fit these, comma-separated: {', '.join(OPTIONAL_FREE)} (q as the ratio q_y/q_x; gps_outlier: "
        "heavy-tailed GPS error, a share of rows with a wider horizontal error, both fitted; mounting: constant pitch and roll "
        "offsets of the receiver's attitude)",
    )
    fixed = p.add_argument_group("fixed model constants (used as given unless fitted)")
    fixed.add_argument("--r-inner", type=_positive, default=3.0, metavar="M", help="inner-zone radius (default 3.0)")
    fixed.add_argument("--r-outer", type=_positive, default=50.0, metavar="M", help="outer limit of d (default 50.0)")
    fixed.add_argument(
        "--q", type=_q_triple, default=(1.0, 1.0, 1.0), metavar="QX,QY,QZ", help="antenna noise sensitivities (default 1,1,1)"
    )
    fixed.add_argument(
        "--pose-sigma",
        type=_positive,
        metavar="S",
        help="fix the relative pose error (default: fitted with exact poses, 0.001 otherwise; e.g. 0.01)",
    )
    fixed.add_argument("--antennas", type=int, choices=(2, 3), default=3, help="receiver class (default 3)")
    fixed.add_argument(
        "--time-offset",
        type=TIME_OFFSET,
        default=None,
        metavar="SEC",
        help="evaluate readings at the poses of t + SEC (default: 0, after a scan over +-3 s finds no better offset)",
    )
    fixed.add_argument(
        "--gps-sigma",
        type=_gps_sigma,
        metavar="H[,V]",
        help="the receiver GPS error, horizontal [and vertical] 1-sigma in m, instead of estimating it "
        "(V defaults to 1.5 H; 0 = exact positions)",
    )
    fixed.add_argument(
        "--attitude-sigma",
        type=_attitude_degrees,
        metavar="DEG",
        help="the receiver attitude error, 1-sigma per axis in degrees, instead of estimating it (0 = exact)",
    )
    fixed.add_argument(
        "--gps-grade",
        choices=tuple(GPS_GRADES),
        help="the GPS error from the receiver's grade instead of estimating it: "
        + ", ".join(f"{k} {v:g} m" for k, v in GPS_GRADES.items())
        + " horizontal (vertical 1.5x)",
    )
    fixed.add_argument(
        "--imu-grade",
        choices=tuple(IMU_GRADES),
        help="the attitude error from the IMU's grade instead of estimating it: "
        + ", ".join(f"{k} {v:g} deg" for k, v in IMU_GRADES.items()),
    )
    p.add_argument(
        "--receiver", metavar="NAME", help="a session directory with several receivers: fit this one (its device name in the session)"
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of the report's simulations and the subsample (default 0)")
    p.set_defaults(func=run)


#: Model distances (m): above 0, at most what the protocol can carry (9,999,999 cm).
_positive = real(0.0, 99_999.99, lo_open=True)
#: A receiver's output latency is well under a minute; an hour is generous.
TIME_OFFSET = real(-3600.0, 3600.0)


#: A pose-error sigma: 0 (exact) or more; metres for GPS, degrees for attitude.
_gps_metres = real(0.0, 99_999.99)
_attitude_degrees = real(0.0, 180.0)


def _gps_sigma(text: str) -> tuple[float, float]:
    parts = text.split(",")
    if len(parts) > 2:
        raise argparse.ArgumentTypeError(f"expected H or H,V (metres), got {text!r}")
    h = _gps_metres(parts[0])
    v = _gps_metres(parts[1]) if len(parts) == 2 else GPS_GRADE_RATIO * h
    if (h == 0) != (v == 0):
        raise argparse.ArgumentTypeError(f"horizontal and vertical must both be 0 or both > 0, got {text!r}")
    return h, v


def _q_triple(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    try:
        q = tuple(float(x) for x in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected three numbers QX,QY,QZ, got {text!r}") from None
    if len(q) != 3 or not all(0 < v <= 1 for v in q):
        raise argparse.ArgumentTypeError(f"expected three numbers in (0, 1], got {text!r}")
    return q  # type: ignore[return-value]


def load_input(arg: str, receiver: str | None = None):
    """The normative table from a CSV path, '-' (stdin) or a session directory (of one
    receiver: ``receiver`` names it when the session has several)."""
    from .csvio import parse_csv, read_csv, validate
    from .table import FitInputError, Table

    path = Path(arg)
    if receiver is not None and (arg == "-" or not path.is_dir()):
        raise FitInputError(f"--receiver {receiver}: only for a session directory (a CSV holds one receiver's rows)")
    if arg == "-":
        return parse_csv(sys.stdin.buffer.read(), "<stdin>")
    if not path.is_dir():
        return read_csv(path)
    from bench import export  # through the module: tests substitute export_rows
    from firmware_proto.errors import InputError

    try:
        out = export.export_rows(path, **({} if receiver is None else {"receiver": receiver}))
    except InputError as exc:
        raise FitInputError(f"{arg}: {exc}") from None
    names = getattr(out, "receivers", ())
    if len(names) > 1:  # their rows one after the other are not one campaign
        raise FitInputError(
            f"{arg}: {len(names)} receivers ({', '.join(names)}): the fit calibrates one; choose it with --receiver NAME"
        )
    table = Table.from_mapping(arg, out.columns)
    validate(table)
    return table


def options_from_args(args):
    from .result import FitOptions
    from .likelihood import Params
    from .table import FitInputError

    extra: list[str] = []
    fit_pose_sigma = False
    for item in args.fit:
        for name in item.split(","):
            name = name.strip()
            if not name:
                continue
            if name in ("kappa_eq", "r_en"):
                continue  # always fitted
            if name == "pose_sigma":
                if args.pose_sigma is not None:
                    raise FitInputError("--fit pose_sigma and --pose-sigma contradict each other")
                fit_pose_sigma = True
                continue
            if name not in OPTIONAL_FREE:
                raise FitInputError(f"--fit: unknown parameter {name!r} (choose from {', '.join(OPTIONAL_FREE)})")
            for one in ALIASES.get(name, (name,)):
                if one not in extra:
                    extra.append(one)
    # The pose error: GPS and attitude sigmas estimated unless given; with both given as 0
    # (exact poses) the relative pose_sigma is fitted instead, as before the errors-in-variables model.
    gps = args.gps_sigma
    att = args.attitude_sigma
    if args.gps_grade is not None:
        if gps is not None:
            raise FitInputError("--gps-grade and --gps-sigma contradict each other; give one")
        gps = (GPS_GRADES[args.gps_grade], GPS_GRADE_RATIO * GPS_GRADES[args.gps_grade])
    if args.imu_grade is not None:
        if att is not None:
            raise FitInputError("--imu-grade and --attitude-sigma contradict each other; give one")
        att = IMU_GRADES[args.imu_grade]
    eiv = not (gps is not None and gps[0] == 0 and att is not None and att == 0)
    if "gps_outlier" in extra and gps is not None and gps[0] == 0:
        raise FitInputError("--fit gps_outlier needs a GPS error to widen, not --gps-sigma 0")
    pose_free = args.pose_sigma is None and (not eiv or fit_pose_sigma)
    free = (
        ["kappa_eq", "r_en"]
        + extra
        + (["pose_sigma"] if pose_free else [])
        + (["gps_sigma"] if eiv and gps is None else [])
        + (["attitude_sigma"] if eiv and att is None else [])
    )
    base = Params(
        r_inner=args.r_inner,
        r_outer=args.r_outer,
        q=tuple(args.q),
        pose_sigma=args.pose_sigma if args.pose_sigma is not None else 1e-3,
        time_offset=args.time_offset if args.time_offset is not None else 0.0,
        antennas=args.antennas,
        gps_sigma=gps[0] if gps is not None else 0.0,
        gps_ratio=(gps[1] / gps[0]) if gps is not None and gps[0] > 0 else GPS_GRADE_RATIO,
        attitude_sigma=math.radians(att) if att is not None else 0.0,
    )
    if args.r_outer <= args.r_inner:
        raise FitInputError(f"--r-outer {args.r_outer:g} must exceed --r-inner {args.r_inner:g}")
    from .params import FREE_PARAMS

    return FitOptions(
        free=tuple(n for n in FREE_PARAMS if n in free),
        base=base,
        seed=args.seed,
        eiv_floor=args.pose_sigma is None,
        scan_offset=args.time_offset is None,
    )


def summary(result) -> str:
    p = result.params
    lines = [f"fit: {result.source}: {result.n_rows} rows, {result.n_censored} with d = -1"]

    def row(name, value, unit="", extra=""):
        se = result.se.get(name)
        pm = f" +- {se:.3g}" if name in result.free and se is not None and se == se else ""
        return f"{name:<11} = {value:.6g}{pm}{unit}{extra}"

    lines.append(row("kappa_eq", p.kappa_eq, "", "   (for transmitter moment s = 1)"))
    lines.append(row("r_en", p.r_en, " m"))
    if not result.separable:
        lines[-1] = f"{'r_en':<11} = not determined: pose error and EMI noise cannot be told apart (see note)"
    if "pose_sigma" in result.free:
        lines.append(row("pose_sigma", p.pose_sigma))
    if "gps_sigma" in result.free:
        se = result.se.get("gps_sigma")
        pm = f" +- {se:.3g}" if se is not None and se == se else ""
        lines.append(f"{'gps_sigma':<11} = {p.gps_sigma:.4g}{pm} m horizontal, {p.gps_ratio * p.gps_sigma:.4g} m vertical")
    if "attitude_sigma" in result.free:
        se = result.se.get("attitude_sigma")
        pm = f" +- {math.degrees(se):.3g}" if se is not None and se == se else ""
        lines.append(f"{'attitude':<11} = {math.degrees(p.attitude_sigma):.4g}{pm} deg")
    if "r_outer" in result.free:
        lines.append(row("r_outer", p.r_outer, " m"))
    if "time_offset" in result.free:
        lines.append(row("time_offset", p.time_offset, " s"))
    if "dropout" in result.free:
        lines.append(row("dropout", p.dropout, "", "   (rows that read -1 whatever the signal)"))
    if "gps_outlier" in result.free:
        lines.append(
            row("gps_outlier", p.gps_outlier, "", f"   (rows whose horizontal GPS error is {p.gps_outlier_scale:.3g}x wider"
                + (f" +- {result.se['gps_outlier_scale']:.3g}" if _has_se(result, "gps_outlier_scale") else "") + ")")
        )  # fmt: skip
    if "mount_pitch" in result.free or "mount_roll" in result.free:
        parts = [
            f"{label} {math.degrees(getattr(p, name)):+.3g}" + (f" +- {math.degrees(result.se[name]):.2g}" if _has_se(result, name) else "")
            for label, name in (("pitch", "mount_pitch"), ("roll", "mount_roll")) if name in result.free
        ]  # fmt: skip
        lines.append(f"{'mounting':<11} = {', '.join(parts)} deg   (the receiver's attitude against the logged one)")
    if "q" in result.free:
        lines.append(f"{'q':<11} = {', '.join(f'{v:.4g}' for v in p.q)}   (q_y/q_x +- {result.se.get('q', float('nan')):.3g})")
    if result.hac_lag == result.hac_lag:
        lines.append(
            f"standard errors: sandwich with time blocks (Newey-West, {result.hac_lag:.0f} s, "
            "fixed-b scaled), robust to pose errors correlated in time"
        )
    status = "converged" if result.converged else f"DID NOT CONVERGE ({result.message})"
    lines.append(f"log-likelihood {result.log_likelihood:.2f}; {status}; {result.iterations} iterations, {result.seconds:.2f} s")
    if result.goodness_of_fit is not None:
        lines.append(result.goodness_of_fit.summary())
    lines += [f"note: {n}" for n in result.notes]
    nv = result.naive
    lines.append(f"naive least squares on detected rows only: kappa_eq {nv['kappa_eq']:.6g}, r_en {nv['r_en']:.4g} m")
    return "\n".join(lines)


def _has_se(result, name: str) -> bool:
    se = result.se.get(name)
    return name in result.free and se is not None and se == se


def run(args: argparse.Namespace) -> int:
    from .estimate import fit_table
    from .report import write_report
    from .scene import write_scene

    options = options_from_args(args)
    # Outputs written after the fit are proved writable now (/proc/x as root passes the
    # permission bits): one line before minutes of fitting, not after.
    if args.report is not None:
        probe_creatable_dir(args.report, "fit: --report")
    if args.write_scene is not None:
        probe_writable(args.write_scene, "fit: --write-scene")
    # Stages, not iterations: the optimiser's count is not known ahead. Transient, on a
    # terminal's stderr only; gone before the summary reaches stdout.
    with progress(f"fit: reading {args.input}") as bar:
        table = load_input(args.input, args.receiver)
        bar.update(description=f"fit: fitting {len(table):,} rows")
        result = fit_table(table, options)
    if args.json:
        print(json.dumps(result.to_json(), allow_nan=False))
    else:
        print(summary(result))
    sys.stdout.flush()
    if args.report is not None:
        md, png, warning = write_report(args.report, table, result, seed=args.seed)
        print(f"arva-bench: fit: wrote {md}" + (f" and {png}" if png else ""), file=sys.stderr)
        if warning:
            print(f"arva-bench: fit: {warning}", file=sys.stderr)
    if not result.converged:
        print(f"arva-bench: fit: did not converge: {result.message}", file=sys.stderr)
        if args.write_scene is not None:
            print(f"arva-bench: fit: not writing {args.write_scene}: no converged estimate", file=sys.stderr)
        return 1
    if args.write_scene is not None:
        how = write_scene(args.write_scene, result)
        print(f"arva-bench: fit: {how} {args.write_scene}", file=sys.stderr)
    return 0
