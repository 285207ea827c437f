"""A minimal TOML writer for the fuzz tests (the standard library only reads TOML).

Not a test module. Handles what the generated documents contain: nested tables, arrays of
tables, scalars (str, int, float incl. nan/inf, bool) and arrays of scalars or arrays.
"""

import json
import math


def _scalar(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # JSON's escapes (\n, \", \uXXXX) are valid in TOML basic strings
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_scalar(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {_scalar(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"cannot emit {type(v).__name__}")


def _is_table_array(v):
    return isinstance(v, list) and v and all(isinstance(x, dict) for x in v)


def dumps(doc: dict, _prefix: str = "") -> str:
    lines, tables = [], []
    for k, v in doc.items():
        key = json.dumps(str(k))
        if isinstance(v, dict):
            tables.append((key, v))
        elif _is_table_array(v):
            tables.append((key, v))
        else:
            lines.append(f"{key} = {_scalar(v)}")
    out = "\n".join(lines) + ("\n" if lines else "")
    for key, v in tables:
        name = f"{_prefix}.{key}" if _prefix else key
        if isinstance(v, dict):
            out += f"\n[{name}]\n" + dumps(v, name)
        else:
            for item in v:
                out += f"\n[[{name}]]\n" + dumps(item, name)
    return out
