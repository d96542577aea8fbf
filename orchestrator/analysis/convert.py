"""Write a log's signals for other tools: CSV or Parquet.

CSV: a header ``t [s], unit.variable [unit], ...`` (no brackets after a name without unit),
then one row per logged time; floats as Python ``repr`` (they read back bit for bit), Booleans
as ``True``/``False``, a missing sample empty. Parquet (pyarrow): a column ``t`` (s) and one
column per ``unit.variable`` with its logged type; each field's metadata holds ``unit`` and
``type``, the file's metadata the source log.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterable

from ..errors import ImmersimError
from .logs import read_log, unit_label

FORMATS = (".csv", ".parquet")


class ConvertError(ImmersimError, ValueError):
    """An output format immersim cannot write."""


def convert_log(log: Path | str, output: Path | str, patterns: Iterable[str] = ("*",)) -> Path:
    """Write the signals of ``log`` matching ``patterns`` to ``output`` (``.csv`` or ``.parquet``).

    Returns
    -------
    Path
        ``output``.
    """
    output = Path(output)
    if output.suffix.lower() not in FORMATS:
        raise ConvertError(f"{output}: unknown output format {output.suffix!r} (use {' or '.join(FORMATS)})")
    df = read_log(log, patterns)
    output.parent.mkdir(parents=True, exist_ok=True)
    if output.suffix.lower() == ".csv":
        units = df.attrs["units"]
        out = df.rename(columns=lambda c: unit_label(c, units))
        out.index.name = "t [s]"
        out.to_csv(output, float_format=lambda x: repr(float(x)))
        return output
    import pyarrow as pa
    import pyarrow.parquet as pq

    units, types = df.attrs["units"], df.attrs["types"]
    df.attrs = {}  # carried by the fields' metadata instead
    table = pa.Table.from_pandas(df, preserve_index=True)
    fields = [f.with_metadata({"unit": units.get(f.name, "s" if f.name == "t" else ""),
                               "type": types.get(f.name, "number")}) for f in table.schema]
    meta = {**(table.schema.metadata or {}), b"immersim.log": str(log).encode()}
    pq.write_table(table.cast(pa.schema(fields, metadata=meta)), output)
    return output
