"""Reading back rerun recordings with rerun's own reader."""

from __future__ import annotations


def rows_per_entity(path) -> dict[str, int]:
    """Entity path -> number of rows logged over time in an .rrd file (static rows such as series names or an
    image format are left out); asserts the recording carries a blueprint."""
    from rerun.experimental import RrdReader

    reader = RrdReader(str(path))
    assert reader.blueprints, "the recording should carry its default blueprint"
    rows: dict[str, int] = {}
    for line in str(reader.store().summary()).splitlines():
        if line.startswith("/") and "static=True" not in line:
            entity = line.split()[0]
            rows[entity] = rows.get(entity, 0) + int(line.split("rows=")[1].split()[0])
    return rows
