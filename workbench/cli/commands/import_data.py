"""``workbench import FILE --out DATA.npz [--map MAP.toml]``: a data file to a spec measurement.

UFF, .mat, CSV or a plain table.

The format comes from FILE's suffix (``.uff``/``.unv``, ``.mat``, ``.csv``/``.tsv``,
``.dat``/``.txt``/``.asc``: numbers without a header, the map naming the columns);
the map says what the file does not (:mod:`workbench.io.importers.mapping`).
The measurement is written in the spec's format (1a time record or 1b FRF),
SI units; what the importer did (unit conversions, a dropped 0 Hz line,
records left out) is printed as ``note:`` lines.
"""

from __future__ import annotations

import argparse

from workbench.core.atomic import check_not_input
from workbench.io.formats import FrfData, save_measurement


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "import",
        help="import a UFF58, MATLAB .mat, CSV or plain table as a spec measurement .npz",
        description=(
            "Read FRFs or time records from a universal file (dataset 58), a MATLAB .mat "
            "(v4-v7.3), a CSV file with a header or a numeric table without one (.dat, .txt: "
            "DaISy's records), and write them as a spec measurement "
            "(kind 'time' or 'frf', SI units). --map names what the file does not say: which "
            "variable, column or channel is which input/output, fs, units."
        ),
    )
    p.add_argument(
        "file", metavar="FILE", help="data file: .uff/.unv, .mat, .csv/.tsv, .dat/.txt/.asc"
    )
    p.add_argument("--out", required=True, metavar="DATA.npz", help="output measurement .npz")
    p.add_argument("--map", metavar="MAP.toml", help="map file: channels, fs, units")
    return p


def run(args) -> int:
    from workbench.io.importers import read_data_file

    check_not_input(args.out, [args.file, args.map])
    got = read_data_file(args.file, args.map)
    save_measurement(args.out, got.data)
    data = got.data
    if isinstance(data, FrfData):
        shape = (
            f"frf, {data.n_y} outputs x {data.n_u} inputs, {data.n_f} lines "
            f"{data.freq[0]:g}..{data.freq[-1]:g} Hz"
        )
    else:
        shape = (
            f"time, {data.n_u} inputs, {data.n_y} outputs, {data.n_samples} samples at "
            f"{data.fs:g} Hz, {data.loop} loop" + (", with r" if data.r is not None else "")
        )
    print(f"wrote {args.out}: {shape} (from {args.file}: {got.description})")
    for note in got.notes:
        print(f"note: {note}")
    return 0
