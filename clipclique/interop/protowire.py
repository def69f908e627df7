"""The protobuf wire format, decoded by hand: what Osmap's binary map files need, no generated code.

A message is a sequence of fields `(number << 3 | wire type, value)`: varints (0), 64-bit (1),
length-delimited bytes (2: strings, sub-messages, packed repeated scalars) and 32-bit (5).
A repeated scalar may come packed (one length-delimited run) or unpacked (one field each);
`repeated_*` accept both, as proto3 readers must. The `encode_*` functions write the packed form
(tools/interop_example.py writes Osmap files of the generated scenes with them).
"""

from __future__ import annotations

import struct
from collections import defaultdict

from clipclique.interop.errors import InteropError

Fields = dict[int, list[int | bytes]]  # field number -> values in order: int (varint) or bytes (the rest)


def _varint(data: bytes, at: int, where: str) -> tuple[int, int]:
    value = shift = 0
    while True:
        if at >= len(data):
            raise InteropError(f"{where}: truncated protobuf (a varint runs past the end)")
        byte = data[at]
        at += 1
        value |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return value, at
        shift += 7
        if shift >= 70:
            raise InteropError(f"{where}: malformed protobuf (a varint longer than 10 bytes)")


def parse_message(data: bytes, where: str) -> Fields:
    """The fields of one message; InteropError naming `where` on truncated or malformed bytes."""
    fields: Fields = defaultdict(list)
    at = 0
    while at < len(data):
        key, at = _varint(data, at, where)
        number, wire = key >> 3, key & 7
        if number == 0:
            raise InteropError(f"{where}: malformed protobuf (field number 0 at byte {at})")
        if wire == 0:
            value, at = _varint(data, at, where)
        elif wire in (1, 5):
            size = 8 if wire == 1 else 4
            if at + size > len(data):
                raise InteropError(f"{where}: truncated protobuf (field {number} runs past the end)")
            value, at = data[at:at + size], at + size
        elif wire == 2:
            size, at = _varint(data, at, where)
            if at + size > len(data):
                raise InteropError(f"{where}: truncated protobuf (field {number} declares {size} bytes, "
                                   f"{len(data) - at} remain)")
            value, at = data[at:at + size], at + size
        else:
            raise InteropError(f"{where}: malformed protobuf (wire type {wire} of field {number}); "
                               "is this an Osmap map file?")
        fields[number].append(value)
    return fields


def submessages(fields: Fields, number: int, where: str) -> list[Fields]:
    """The repeated (or single) sub-message field `number`, each parsed."""
    out = []
    for index, value in enumerate(fields.get(number, [])):
        if not isinstance(value, bytes):
            raise InteropError(f"{where}: field {number} should be a message, got a varint")
        out.append(parse_message(value, f"{where}, element {index}"))
    return out


def repeated_uint(fields: Fields, number: int, where: str) -> list[int]:
    """A repeated unsigned integer field, packed or unpacked."""
    out: list[int] = []
    for value in fields.get(number, []):
        if isinstance(value, int):
            out.append(value)
            continue
        at = 0
        while at < len(value):
            item, at = _varint(value, at, where)
            out.append(item)
    return out


def single_uint(fields: Fields, number: int, where: str, default: int | None = None) -> int:
    """The last value of a scalar unsigned field (proto3: the last one wins), `default` when absent."""
    values = repeated_uint(fields, number, where)
    if values:
        return values[-1]
    if default is None:
        raise InteropError(f"{where}: field {number} missing")
    return default


def repeated_float(fields: Fields, number: int, where: str, double: bool = False) -> list[float]:
    """A repeated float (or double) field, packed (one run) or unpacked (one 32/64-bit value each)."""
    size, code = (8, "d") if double else (4, "f")
    out: list[float] = []
    for value in fields.get(number, []):
        if isinstance(value, int) or len(value) % size:
            raise InteropError(f"{where}: field {number} should hold {'doubles' if double else 'floats'}")
        out.extend(struct.unpack(f"<{len(value) // size}{code}", value))
    return out


def encode_varint(value: int) -> bytes:
    """A varint: 7 bits per byte, low bits first, the high bit set on every byte but the last."""
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def encode_field(number: int, value: int | bytes) -> bytes:
    """One field: a varint for an int, length-delimited bytes (a sub-message, a packed run) otherwise."""
    if isinstance(value, int):
        return encode_varint(number << 3) + encode_varint(value)
    return encode_varint(number << 3 | 2) + encode_varint(len(value)) + value


def encode_packed_uints(number: int, values: list[int]) -> bytes:
    return encode_field(number, b"".join(encode_varint(v) for v in values))


def encode_packed_floats(number: int, values: list[float]) -> bytes:
    return encode_field(number, struct.pack(f"<{len(values)}f", *values))
