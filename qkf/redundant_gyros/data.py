"""Recorded gyro readings (``--data DATA.csv``): reading and checking (docs/redundant_gyros.md,
"Recorded data").

The file has a header with ``t_s`` and one column per gyro id of the config (deg/s, the raw
readings ``m_i``); other columns are ignored. A missing column, a time that does not increase,
or a value that is not a finite number is refused with a :class:`DataError` naming the file,
the line and the column.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from qkf.redundant_gyros.scenario import GyroData


class DataError(ValueError):
    """A data file that cannot be used; the message names the file, line and column."""


def _number(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def load_readings(path: str | Path, ids: tuple[str, ...] | list[str]) -> GyroData:
    """Readings of one recorded trial: ``GyroData`` with B = 1 and no truth."""
    p = Path(path)
    if not p.is_file():
        raise DataError(f"{p}: no such data file")
    try:
        with p.open(newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except UnicodeDecodeError as exc:
        raise DataError(f"{p}: not a text file (UTF-8): {exc.reason}") from None
    except csv.Error as exc:
        raise DataError(f"{p}: not a CSV file: {exc}") from None
    if not rows:
        raise DataError(f"{p}: empty file (expected a header with t_s and {', '.join(ids)})")
    header = [h.strip() for h in rows[0]]
    wanted = ["t_s", *ids]
    for name in wanted:
        if name not in header:
            raise DataError(f"{p}: line 1: missing column {name!r} (need {', '.join(wanted)})")
        if header.count(name) > 1:
            raise DataError(f"{p}: line 1: column {name!r} appears twice")
    cols = [header.index(name) for name in wanted]
    body = [(line, r) for line, r in enumerate(rows[1:], start=2) if any(c.strip() for c in r)]
    if len(body) < 2:
        raise DataError(f"{p}: needs at least two rows of readings")
    values = np.empty((len(body), len(wanted)))
    for row, (line, r) in enumerate(body):
        for k, (name, c) in enumerate(zip(wanted, cols, strict=True)):
            text = r[c].strip() if c < len(r) else ""
            x = _number(text)
            if x is None:
                what = "empty" if not text else f"not a finite number ({text!r})"
                raise DataError(f"{p}: line {line}: column {name}: {what}")
            values[row, k] = x
        if row > 0 and not values[row, 0] > values[row - 1, 0]:
            raise DataError(
                f"{p}: line {line}: column t_s: time does not increase "
                f"({values[row, 0]!r} after {values[row - 1, 0]!r})"
            )
    return GyroData(t=values[:, 0].copy(), meas=values[None, :, 1:].copy(), rate=None, coeffs=None)
