"""Structure check of MATLAB v4 and v5/v7 .mat files, before ``scipy.io.loadmat`` parses them.

scipy's v5 reader is compiled code that trusts the file: a data element of an undefined type code crashes
the process (it indexes a table of dtypes with the code), arrays nested deeply enough exhaust the C stack,
and dimensions with no data behind them make it allocate without bound. :func:`check_mat` walks every data
element of the file with plain Python reads (decompressing each ``miCOMPRESSED`` element with zlib as it
goes) and raises :class:`MatStructureError` unless the file holds only what scipy reads safely and a run
log can use: numeric, char, cell and struct arrays whose every tag, size and dimension agree.

MAT-file layout: MathWorks, "MAT-File Format" (matfile_format.pdf): a 128-byte header, then data elements,
each an 8-byte tag (type, byte count; or the 4-byte "small data element" form) and its data, padded to 8
bytes. An array (miMATRIX) holds array flags, dimensions, a name, then its class's data. A v4 file is a
sequence of 20-byte headers (type code, rows, columns, imaginary flag, name length), each followed by the
name and the data.
"""

from __future__ import annotations

import struct
import zlib
from math import prod
from typing import BinaryIO

MI_INT8, MI_UINT8, MI_INT16, MI_UINT16, MI_INT32, MI_UINT32, MI_SINGLE, MI_DOUBLE = 1, 2, 3, 4, 5, 6, 7, 9
MI_INT64, MI_UINT64, MI_MATRIX, MI_COMPRESSED, MI_UTF8, MI_UTF16, MI_UTF32 = 12, 13, 14, 15, 16, 17, 18
NUMERIC_BYTES = {MI_INT8: 1, MI_UINT8: 1, MI_INT16: 2, MI_UINT16: 2, MI_INT32: 4, MI_UINT32: 4, MI_SINGLE: 4,
                 MI_DOUBLE: 8, MI_INT64: 8, MI_UINT64: 8}
CHAR_BYTES = {MI_INT8: 1, MI_UINT8: 1, MI_UINT16: 2, MI_UTF16: 2, MI_UTF32: 4, MI_UTF8: None}  # UTF-8: 1 to 4
NAME_TYPES = {MI_INT8: 1, MI_UTF8: 1}
DIM_TYPES = {MI_INT32: 4, MI_UINT32: 4}

MX_CELL, MX_STRUCT, MX_CHAR = 1, 2, 4
MX_NUMERIC = range(6, 16)  # double, single, int8 ... uint64
OTHER_CLASSES = {3: "a MATLAB object", 5: "a sparse array", 16: "a function handle", 17: "a MATLAB object"}

HEADER_BYTES = 128
MAX_DEPTH = 8  # arrays in arrays: a run log's 'units' is a struct or a cell of char arrays (depth 1)
MAX_ARRAYS = 1 << 20  # cells and struct fields in one file
MAX_EMPTY = 1 << 20  # elements of a char array without data or of a struct without fields (scipy allocates them)
MAX_ARRAY_BYTES = 1 << 31  # MATLAB's v7 limit for one variable; larger ones need v7.3
CHUNK = 1 << 20

V4_TYPES = {0: 8, 1: 4, 2: 4, 3: 2, 4: 2, 5: 1}  # P digit of the type code -> bytes per value
V5_MARKS = {b"\x00\x01IM": "<", b"\x01\x00MI": ">"}
V73_MARKS = (b"\x00\x02IM", b"\x02\x00MI")


class MatStructureError(ValueError):
    """A .mat file that is not one :func:`check_mat` vouches for; the message says what and where."""


def checked_mat(fh: BinaryIO, size: int, max_bytes: int) -> bytes:
    """The v4 or v5/v7 .mat file open in ``fh`` (``size`` bytes) as checked, or MatStructureError.

    The bytes returned are the ones checked, for scipy to parse: a v4 file as it is, a v5 file with every
    variable uncompressed (so scipy does not inflate it a second time); more than ``max_bytes`` of them are
    refused (a few megabytes of zlib data can inflate to gigabytes). The version is taken as
    ``scipy.io.matlab.matfile_version`` takes it: a zero byte among the first four makes a v4 file,
    otherwise bytes 124-127 give the version and byte order.
    """
    fh.seek(0)
    head = fh.read(HEADER_BYTES)
    if len(head) < 20:
        raise MatStructureError(f"the file has {len(head)} bytes; a .mat file has a header of at least 20")
    if not any(head[:20]):
        raise MatStructureError("the file's first 20 bytes are zero")
    if 0 in head[:4]:
        if size > max_bytes:
            raise MatStructureError(f"the file has {size} bytes; at most {max_bytes} are read")
        _check_v4(fh, size)
        fh.seek(0)
        return fh.read()
    if len(head) < HEADER_BYTES:
        raise MatStructureError(f"the file has {len(head)} bytes, less than the {HEADER_BYTES}-byte MATLAB 5 header")
    marks = head[124:128]
    if marks in V73_MARKS:
        raise MatStructureError("the file has a MATLAB v7.3 header but no HDF5 data after it; is it truncated?")
    if marks not in V5_MARKS:
        raise MatStructureError(f"bytes 124-127 are {marks!r}, not a MATLAB 5 version and byte-order mark "
                                f"(b'\\x00\\x01IM')")
    return head + b"".join(_check_v5(fh, size, V5_MARKS[marks], [max_bytes - HEADER_BYTES, max_bytes]))


# ------------------------------------------------------------------------------------------------ v5, v7


def _check_v5(fh: BinaryIO, size: int, order: str, budget: list[int]) -> list[bytes]:
    """The variables after the header, each an uncompressed miMATRIX element; ``budget`` is [bytes left,
    limit], drawn down as they are read."""
    pos, names, arrays, elements = HEADER_BYTES, set(), [0], []
    while pos < size:
        if size - pos < 8:
            raise MatStructureError(f"the file ends inside a data element's tag at byte {pos}")
        fh.seek(pos)
        mdtype, nbytes = struct.unpack(order + "II", fh.read(8))
        if mdtype not in (MI_MATRIX, MI_COMPRESSED):
            raise MatStructureError(f"the data element at byte {pos} has type {mdtype}; a variable is miMATRIX "
                                    f"({MI_MATRIX}) or miCOMPRESSED ({MI_COMPRESSED})")
        if not 0 < nbytes <= size - pos - 8:
            raise MatStructureError(f"the variable at byte {pos} declares {nbytes} bytes; {size - pos - 8} follow "
                                    f"(is the file cut short?)")
        source, declared = _Source(fh, nbytes, compressed=mdtype == MI_COMPRESSED, at=pos,
                                  budget=budget), nbytes
        if mdtype == MI_COMPRESSED:
            inner_type, inner_bytes = struct.unpack(order + "II", source.read(8, "the compressed variable"))
            if inner_type != MI_MATRIX or not 0 < inner_bytes <= MAX_ARRAY_BYTES:
                raise MatStructureError(f"the compressed variable at byte {pos} holds a data element of type "
                                        f"{inner_type} and {inner_bytes} bytes; expected an array (miMATRIX, "
                                        f"type {MI_MATRIX}) of at most {MAX_ARRAY_BYTES} bytes")
            nbytes = inner_bytes
        name = _Walk(source, order, arrays).array(nbytes, depth=0, label="")
        source.finish()
        if mdtype == MI_MATRIX:
            elements.append(struct.pack(order + "II", MI_MATRIX, nbytes))
        elements += source.parts
        if name in names:
            raise MatStructureError(f"variable {name!r} appears twice")
        names.add(name)
        pos += 8 + declared  # as scipy goes on: no padding after a variable
    if not names:
        raise MatStructureError(f"the file holds no variables after its {HEADER_BYTES}-byte header (is it cut short?)")
    return elements


class _Source:
    """The bytes of one top-level variable, read in order: from the file, or inflated from its zlib stream.

    ``parts`` keeps every byte produced, so that what was checked is what is parsed.
    """

    def __init__(self, fh: BinaryIO, nbytes: int, *, compressed: bool, at: int, budget: list[int]) -> None:
        self.fh, self.left, self.at, self.budget = fh, nbytes, at, budget
        self.inflate = zlib.decompressobj() if compressed else None
        self.buffer, self.offset, self.pos = b"", 0, 0
        self.parts: list[bytes] = []

    def read(self, n: int, what: str) -> bytes:
        """The next ``n`` bytes; MatStructureError naming ``what`` if the variable ends first."""
        parts, wanted = [], n
        while n:
            if self.offset == len(self.buffer) and not self._fill():
                raise MatStructureError(f"the variable at byte {self.at} ends inside {what}")
            part = self.buffer[self.offset:self.offset + n]
            self.offset += len(part)
            n -= len(part)
            parts.append(part)
        self.pos += wanted
        return b"".join(parts)

    def skip(self, n: int, what: str) -> None:
        """Pass over the next ``n`` bytes (array data), inflating them but keeping none."""
        while n:
            if self.offset == len(self.buffer) and not self._fill():
                raise MatStructureError(f"the variable at byte {self.at} ends inside {what}")
            step = min(n, len(self.buffer) - self.offset)
            self.offset += step
            self.pos += step
            n -= step

    def finish(self) -> None:
        """For a compressed variable: nothing may follow the array in its zlib stream."""
        if self.inflate is None:
            return
        if self.offset < len(self.buffer) or self._fill():
            raise MatStructureError(f"the compressed variable at byte {self.at} holds bytes after its array")
        if self.inflate.eof and (self.inflate.unused_data or self.left):
            raise MatStructureError(f"the compressed variable at byte {self.at} has data after its zlib stream")

    def _fill(self) -> bool:
        """Refill the buffer; False at the end of the variable."""
        self.buffer, self.offset = b"", 0
        while not self.buffer:
            self.buffer = self._more()
            if self.buffer is None:
                self.buffer = b""
                return False
        self.budget[0] -= len(self.buffer)
        if self.budget[0] < 0:
            raise MatStructureError(f"inflating the variable at byte {self.at} passes the limit of "
                                    f"{self.budget[1]} bytes on a file's content (a zlib stream inflating "
                                    f"without bound?)")
        self.parts.append(self.buffer)
        return True

    def _more(self) -> bytes | None:
        """The next bytes of the variable (possibly none yet); None at its end."""
        if self.inflate is None:
            data = self.fh.read(min(self.left, CHUNK))
            self.left -= len(data)
            return data or None
        if self.inflate.eof:
            return None
        if self.inflate.unconsumed_tail:
            compressed = self.inflate.unconsumed_tail
        elif self.left:
            compressed = self.fh.read(min(self.left, CHUNK))
            self.left -= len(compressed)
        else:
            return None  # a stream without its end marker, as some MATLAB versions write: scipy reads it
        try:
            return self.inflate.decompress(compressed, CHUNK)
        except zlib.error as err:
            raise MatStructureError(f"the compressed variable at byte {self.at} is corrupt (zlib: {err})") from None


class _Walk:
    """Checks arrays read from one :class:`_Source`; ``arrays`` counts nested arrays over the whole file."""

    def __init__(self, source: _Source, order: str, arrays: list[int]) -> None:
        self.source, self.order, self.arrays = source, order, arrays

    def array(self, nbytes: int, depth: int, label: str) -> str:
        """Check the array whose ``nbytes`` bytes (after its tag) come next; its name."""
        end = self.source.pos + nbytes
        if depth > MAX_DEPTH:
            raise MatStructureError(f"{label} nests arrays deeper than {MAX_DEPTH} levels")
        flags_tag = struct.unpack(self.order + "II", self._read(8, end, "array flags"))
        if flags_tag != (MI_UINT32, 8):
            raise MatStructureError(f"{label or 'a variable'}: array flags tagged {flags_tag}, not ({MI_UINT32}, 8)")
        flags = struct.unpack(self.order + "II", self._read(8, end, "array flags"))[0]
        mclass, is_complex = flags & 0xFF, bool(flags & 0x800)
        if mclass == 17:  # opaque: no dimensions
            raise MatStructureError(f"{label or 'a variable'} is {OTHER_CLASSES[17]}; a run log holds numbers, "
                                    f"char arrays, cells and structs")
        dims = self._dims(end, label or "a variable")
        name = self._name(end, label or "a variable")
        label = label or f"variable {name!r}"
        if mclass in MX_NUMERIC:
            for part in ("real", "imaginary")[:1 + is_complex]:
                self._numbers(dims, end, f"{label}'s {part} part")
        elif mclass == MX_CHAR:
            self._chars(dims, end, label)
        elif mclass == MX_CELL:
            self._children(prod(dims), end, depth, label, lambda k: f"{label}, cell {k + 1}")
        elif mclass == MX_STRUCT:
            fields = self._field_names(end, label)
            if not fields and prod(dims) > MAX_EMPTY:
                raise MatStructureError(f"{label} is a struct array of {prod(dims)} elements without fields")
            self._children(prod(dims) * len(fields), end, depth, label,
                           lambda k: f"{label}, field {fields[k % len(fields)]!r}")
        else:
            kind = OTHER_CLASSES.get(mclass, f"an array of unknown class {mclass}")
            raise MatStructureError(f"{label} is {kind}; a run log holds numbers, char arrays, cells and structs")
        if self.source.pos != end:
            raise MatStructureError(f"{label} declares {end - self.source.pos} more bytes than its parts hold")
        return name

    def _read(self, n: int, end: int, what: str) -> bytes:
        if n > end - self.source.pos:
            raise MatStructureError(f"{what} runs past the end of its array")
        return self.source.read(n, what)

    def _element(self, end: int, types: dict, what: str, keep: bool = True) -> tuple[int, int, bytes | None]:
        """Type, byte count and (if ``keep``) data of the next data element, whose type must be in ``types``."""
        tag = self._read(8, end, what)
        first, second = struct.unpack(self.order + "II", tag)
        small = first >> 16
        mdtype, nbytes = (first & 0xFFFF, small) if small else (first, second)
        if mdtype not in types:
            raise MatStructureError(f"{what} has data type {mdtype}; expected one of {sorted(types)}")
        if small:
            if nbytes > 4:
                raise MatStructureError(f"{what}: a small data element of {nbytes} bytes (at most 4)")
            return mdtype, nbytes, tag[4:4 + nbytes]
        padded = nbytes + -nbytes % 8
        if padded > end - self.source.pos:
            raise MatStructureError(f"{what} declares {nbytes} bytes; {end - self.source.pos} remain in its array")
        data = self.source.read(nbytes, what) if keep else self.source.skip(nbytes, what)
        self.source.skip(padded - nbytes, what)
        return mdtype, nbytes, data

    def _dims(self, end: int, label: str) -> list[int]:
        mdtype, nbytes, data = self._element(end, DIM_TYPES, f"{label}'s dimensions")
        if nbytes % 4 or not 2 <= nbytes // 4 <= 32:
            raise MatStructureError(f"{label}'s dimensions take {nbytes} bytes; 2 to 32 dimensions take 8 to 128")
        dims = list(struct.unpack(f"{self.order}{nbytes // 4}i", data))
        if min(dims) < 0:
            raise MatStructureError(f"{label} has negative dimensions {dims}")
        return dims

    def _name(self, end: int, label: str) -> str:
        _, _, data = self._element(end, NAME_TYPES, f"{label}'s name")
        if not data.isascii():
            raise MatStructureError(f"{label}'s name {data!r} is not ASCII")
        return data.decode("ascii")

    def _numbers(self, dims: list[int], end: int, what: str) -> None:
        mdtype, nbytes, _ = self._element(end, NUMERIC_BYTES, what, keep=False)
        count, width = prod(dims), NUMERIC_BYTES[mdtype]
        if nbytes != count * width:
            raise MatStructureError(f"{what} holds {nbytes} bytes of {width}-byte values; its dimensions {dims} "
                                    f"need {count * width}")

    def _chars(self, dims: list[int], end: int, label: str) -> None:
        mdtype, nbytes, _ = self._element(end, CHAR_BYTES, f"{label}'s characters", keep=False)
        count, width = prod(dims), CHAR_BYTES[mdtype]
        fits = (count <= MAX_EMPTY if nbytes == 0 else
                count <= nbytes <= 4 * count if width is None else nbytes == count * width)
        if not fits:
            raise MatStructureError(f"{label} holds {nbytes} bytes of characters (type {mdtype}); its dimensions "
                                    f"{dims} do not fit them")

    def _field_names(self, end: int, label: str) -> list[str]:
        _, nbytes, data = self._element(end, DIM_TYPES, f"{label}'s field name length")
        length = struct.unpack(self.order + "i", data)[0] if nbytes == 4 else 0
        if not 0 < length <= 4096:
            raise MatStructureError(f"{label}'s field name length is {length if nbytes == 4 else '(missing)'}")
        _, nbytes, names = self._element(end, NAME_TYPES, f"{label}'s field names")
        if nbytes % length:
            raise MatStructureError(f"{label}'s field names take {nbytes} bytes, not a multiple of {length}")
        slots = [names[k:k + length] for k in range(0, nbytes, length)]
        if not all(b"\0" in slot and slot.isascii() for slot in slots):
            raise MatStructureError(f"{label}'s field names are not NUL-terminated ASCII")
        return [slot.split(b"\0", 1)[0].decode("ascii") for slot in slots]

    def _children(self, count: int, end: int, depth: int, label: str, child_label) -> None:
        if count > (end - self.source.pos) // 8 or self.arrays[0] + count > MAX_ARRAYS:
            raise MatStructureError(f"{label} declares {count} cells or fields; its bytes (or the limit of "
                                    f"{MAX_ARRAYS} per file) hold fewer")
        self.arrays[0] += count
        for k in range(count):
            what = child_label(k)
            mdtype, nbytes = struct.unpack(self.order + "II", self._read(8, end, what))
            if mdtype != MI_MATRIX:
                raise MatStructureError(f"{what} has data type {mdtype}, not an array (miMATRIX, {MI_MATRIX})")
            if nbytes > end - self.source.pos:
                raise MatStructureError(f"{what} declares {nbytes} bytes; {end - self.source.pos} remain")
            if nbytes:  # zero bytes: an empty array
                self.array(nbytes, depth + 1, what)


# ------------------------------------------------------------------------------------------------------ v4


def _check_v4(fh: BinaryIO, size: int) -> None:
    fh.seek(0)
    first = struct.unpack("<i", fh.read(4))[0]
    order = "<" if 0 <= first <= 5000 else ">"  # as scipy guesses it
    pos, names = 0, set()
    while pos < size:
        fh.seek(pos)
        header = fh.read(20)
        if len(header) < 20:
            raise MatStructureError(f"the file ends inside a MATLAB v4 variable header at byte {pos}")
        mopt, rows, columns, imaginary, name_length = struct.unpack(order + "5i", header)
        order_digit, rest = divmod(mopt, 1000)
        zero, rest = divmod(rest, 100)
        type_digit, class_digit = divmod(rest, 10)
        if not (0 <= mopt < 5000 and order_digit == (0 if order == "<" else 1) and zero == 0 and type_digit in V4_TYPES
                and class_digit in (0, 1) and imaginary in (0, 1) and rows >= 0 and columns >= 0
                and name_length > 0):
            raise MatStructureError(f"the MATLAB v4 variable header at byte {pos} is not one scipy reads as a "
                                    f"full or text matrix: type {mopt}, {rows} x {columns}, imaginary flag "
                                    f"{imaginary}, name length {name_length}")
        nbytes = name_length + V4_TYPES[type_digit] * rows * columns * (1 + imaginary)
        if nbytes > size - pos - 20:
            raise MatStructureError(f"the MATLAB v4 variable at byte {pos} declares {nbytes} bytes; "
                                    f"{size - pos - 20} follow (is the file cut short?)")
        name = fh.read(name_length).strip(b"\0")
        if name in names:
            raise MatStructureError(f"variable {name.decode('latin-1')!r} appears twice")
        names.add(name)
        pos += 20 + nbytes
