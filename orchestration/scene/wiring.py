"""The wiring of a scene: connections ``"fmu.variable -> fmu.variable"`` between its FMUs, by name.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Connection", "parse_connection"]


@dataclass(frozen=True)
class Connection:
    src: str
    src_var: str
    dst: str
    dst_var: str

    def __str__(self):
        return f"{self.src}.{self.src_var} -> {self.dst}.{self.dst_var}"


def parse_connection(text: str) -> Connection:
    """``"plant.phi_o -> controller.phi_o"`` -> :class:`Connection`."""
    try:
        left, right = (s.strip() for s in text.split("->"))
        src, src_var = left.split(".", 1)
        dst, dst_var = right.split(".", 1)
    except ValueError:
        raise ValueError(f"connection {text!r} is not of the form 'fmu.var -> fmu.var'") from None
    return Connection(src, src_var, dst, dst_var)

