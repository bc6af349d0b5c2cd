"""Recorded gyro readings (``--data DATA.csv``): reading and checking (docs/redundant_gyros.md,
"Recorded data").

The file has a header with ``t_s`` and one column per gyro id of the config (deg/s, the raw
readings ``m_i``); other columns are ignored. The file is opened by
:func:`qkf.core.csvfile.read_table` (a directory, a missing file, non-UTF-8 or non-CSV text are
refused there). A missing column, a needed column that appears twice, fewer than two rows, a
time that does not increase, or a value that is not a finite number is refused with a
:class:`DataError` naming the file, the line and the column; values are quoted as the file
writes them.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from qkf.core.csvfile import DataFileError, read_table, refuse_duplicates
from qkf.redundant_gyros.scenario import GyroData

DataError = DataFileError  # this problem's name for it (one class for every data file)


def _number(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def load_readings(path: str | Path, ids: tuple[str, ...] | list[str]) -> GyroData:
    """Readings of one recorded trial: ``GyroData`` with B = 1 and no truth."""
    p = Path(path)
    wanted = ["t_s", *ids]
    header, records = read_table(p, wanted)
    for name in wanted:
        if name not in header:
            raise DataError(f"{p}: line 1: missing column {name!r} (need {', '.join(wanted)})")
    refuse_duplicates(p, header, wanted)
    cols = [header.index(name) for name in wanted]
    body = [(row + 1, r) for row, r in records]  # file line = data row + 1 (the header)
    if len(body) < 2:
        raise DataError(f"{p}: needs at least two rows of readings (has {len(body)})")
    values = np.empty((len(body), len(wanted)))
    texts = []  # t_s as written, for messages (a numpy scalar's repr is np.float64(…))
    for row, (line, r) in enumerate(body):
        for k, (name, c) in enumerate(zip(wanted, cols, strict=True)):
            text = r[c].strip() if c < len(r) else ""
            x = _number(text)
            if x is None:
                what = "empty" if not text else f"not a finite number ({text!r})"
                raise DataError(f"{p}: line {line}: column {name}: {what}")
            values[row, k] = x
        texts.append(r[cols[0]].strip())
        if row > 0 and not values[row, 0] > values[row - 1, 0]:
            raise DataError(
                f"{p}: line {line}: column t_s: time does not increase "
                f"({texts[row]} after {texts[row - 1]} on line {body[row - 1][0]})"
            )
    return GyroData(t=values[:, 0].copy(), meas=values[None, :, 1:].copy(), rate=None, coeffs=None)
