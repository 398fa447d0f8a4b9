"""Byte-level mutations for the readers' fuzz tests (shared by the io test modules)."""

from __future__ import annotations

from hypothesis import strategies as st


def mutation_ops(max_size: int = 6) -> st.SearchStrategy[list[tuple[int, int, int]]]:
    """Lists of (kind, position, value): flip a bit, insert, delete or truncate."""
    return st.lists(
        st.tuples(st.integers(0, 3), st.integers(0, 10**6), st.integers(0, 255)),
        min_size=1,
        max_size=max_size,
    )


def mutate(data: bytes, ops: list[tuple[int, int, int]]) -> bytes:
    """Apply ``ops`` to ``data``: 0 flips a bit, 1 inserts a byte, 2 deletes one, 3 truncates."""
    b = bytearray(data)
    for kind, pos, val in ops:
        if not b:
            break
        i = pos % len(b)
        if kind == 0:
            b[i] ^= 1 << (val % 8)
        elif kind == 1:
            b.insert(i, val % 256)
        elif kind == 2:
            del b[i]
        else:
            del b[i:]
    return bytes(b)
