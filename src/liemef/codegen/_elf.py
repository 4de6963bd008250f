"""Is a shared library whole, and built for this machine? A check of an ELF file's own structure, made on the
bytes about to be handed to ``dlopen``.

A manifest's size and SHA-256 (:mod:`._cache`) say that the bytes are those the build wrote, or those whoever
rewrote the manifest wanted; they do not say that the bytes are a library. A library cut short, with its
manifest rewritten to match, passes that check, and the dynamic loader maps its segments past the end of the
file: the first touch of them raises SIGBUS, and the process dies without a word. :func:`defect` reads what
the loader will read, and says what is wrong before anything is mapped:

* the ELF header: the magic number, a 64-bit little-endian file (``ELFCLASS64``, ``ELFDATA2LSB``), version 1, a
  shared object (``ET_DYN``), for this machine (:func:`host`), with header and table entries of the sizes of
  ELF64;
* the program header table lies inside the file, and so does every segment's part of the file
  (``p_offset + p_filesz``); a loaded segment's file part is not larger than its memory; there is a loadable
  segment, and one dynamic segment inside a loaded one;
* the dynamic section ends with ``DT_NULL`` inside its segment, and each table it points the loader to (string
  and symbol tables, hashes, relocations, initializers, versions) lies in the file part of a loaded segment;
* the section header table lies inside the file, and so does every section that holds bytes (all but
  ``SHT_NOBITS``).

GCC and Clang put the section header table at the end of a library, so a library cut anywhere fails the last
checks at least. The check is of structure, not of trust: a library built to pass it can still do anything
when loaded (see ``docs/engines.md``, the threat model).

The hosts are Linux on x86-64 and on AArch64 (64-bit, little-endian): :func:`host` refuses any other by
name, so the C engine is not used there (``engine="auto"`` runs XLA, with an ``EngineWarning`` saying why).
"""

from __future__ import annotations

import platform
import struct
import sys

MACHINES = {62: "x86-64", 183: "AArch64"}
"""The ELF machines (``e_machine``) liemef loads libraries for, by number."""

_HOSTS = {"x86_64": 62, "amd64": 62, "aarch64": 183, "arm64": 183}  # platform.machine() -> e_machine

_OTHER_MACHINES = {3: "i386", 8: "MIPS", 20: "PowerPC", 21: "PowerPC64", 22: "IBM S/390", 40: "ARM (32-bit)",
                   243: "RISC-V", 258: "LoongArch"}

_HEADER = struct.Struct("<16sHHIQQQIHHHHHH")  # Elf64_Ehdr
_PHDR = struct.Struct("<IIQQQQQQ")  # Elf64_Phdr
_SHDR = struct.Struct("<IIQQQQIIQQ")  # Elf64_Shdr
_DYN = struct.Struct("<qQ")  # Elf64_Dyn
ET_DYN, PT_LOAD, PT_DYNAMIC, SHT_NOBITS, DT_NULL = 3, 1, 2, 8, 0

# dynamic tags that point the loader to a table: tag -> (its name, the tag of its size in bytes, or None)
_TABLES = {4: ("DT_HASH", None), 5: ("DT_STRTAB", 10), 6: ("DT_SYMTAB", None), 7: ("DT_RELA", 8),
           17: ("DT_REL", 18), 23: ("DT_JMPREL", 2), 25: ("DT_INIT_ARRAY", 27), 26: ("DT_FINI_ARRAY", 28),
           36: ("DT_RELR", 35), 0x6FFFFEF5: ("DT_GNU_HASH", None), 0x6FFFFFF0: ("DT_VERSYM", None),
           0x6FFFFFFC: ("DT_VERDEF", None), 0x6FFFFFFE: ("DT_VERNEED", None)}


def host() -> int:
    """This machine's ELF ``e_machine``: Linux on x86-64 or AArch64, a 64-bit little-endian Python.
    RuntimeError naming the system otherwise (the C engine loads ELF libraries for these only)."""
    machine = platform.machine()
    code = _HOSTS.get(machine.lower())
    if not sys.platform.startswith("linux") or code is None or struct.calcsize("P") != 8 \
            or sys.byteorder != "little":
        raise RuntimeError(f"the C engine loads ELF libraries on 64-bit Linux for {' and '.join(MACHINES.values())} "
                           f"only; this is {sys.platform} on {machine or 'an unknown machine'} "
                           f"({8 * struct.calcsize('P')}-bit, {sys.byteorder}-endian)")
    return code


def _machine(code: int) -> str:
    name = MACHINES.get(code) or _OTHER_MACHINES.get(code)
    return f"{name} (e_machine {code})" if name else f"e_machine {code}"


def defect(data: bytes, machine: int | None = None) -> str | None:
    """What keeps ``data`` from being a whole ELF shared library for ``machine`` (default: :func:`host`), or
    None if nothing does. Every answer names the defect, e.g. ``"segment 1 (PT_LOAD) ends at byte 10653, past
    the end of the file (4096 bytes)"``."""
    if machine is None:
        machine = host()
    size = len(data)
    if size < _HEADER.size or data[:4] != b"\x7fELF":
        return f"not an ELF file (it starts with {bytes(data[:4])!r}, {size} bytes)"
    (ident, e_type, e_machine, e_version, _, phoff, shoff, _, ehsize, phentsize, phnum, shentsize, shnum,
     _) = _HEADER.unpack_from(data)
    if ident[4] != 2:
        return f"not a 64-bit ELF file (EI_CLASS {ident[4]})"
    if ident[5] != 1:
        return f"not a little-endian ELF file (EI_DATA {ident[5]})"
    if ident[6] != 1 or e_version != 1:
        return f"an ELF file of unknown version {ident[6]}/{e_version}"
    if e_type != ET_DYN:
        return f"not a shared library (e_type {e_type}, expected ET_DYN = {ET_DYN})"
    if e_machine != machine:
        return f"built for {_machine(e_machine)}, not for this machine's {_machine(machine)}"
    if ehsize != _HEADER.size or phentsize != _PHDR.size or (shnum and shentsize != _SHDR.size):
        return (f"its header sizes (ELF header {ehsize}, program header {phentsize}, section header {shentsize} "
                f"bytes) are not ELF64's ({_HEADER.size}, {_PHDR.size}, {_SHDR.size})")
    if not phnum or phnum == 0xFFFF:
        return "no program headers" if not phnum else "an extended count of program headers (e_phnum 0xffff)"
    if phoff + phnum * _PHDR.size > size:
        return (f"its program header table (bytes {phoff} to {phoff + phnum * _PHDR.size}) ends past the end of "
                f"the file ({size} bytes)")
    loads, dynamic = [], []
    for i in range(phnum):
        p_type, _, offset, vaddr, _, filesz, memsz, _ = _PHDR.unpack_from(data, phoff + i * _PHDR.size)
        name = {PT_LOAD: " (PT_LOAD)", PT_DYNAMIC: " (PT_DYNAMIC)"}.get(p_type, "")
        if offset + filesz > size:
            return f"segment {i}{name} ends at byte {offset + filesz}, past the end of the file ({size} bytes)"
        if p_type == PT_LOAD:
            if filesz > memsz:
                return f"segment {i} (PT_LOAD) holds {filesz} bytes of the file in {memsz} bytes of memory"
            loads.append((offset, vaddr, filesz))
        elif p_type == PT_DYNAMIC:
            dynamic.append((i, offset, filesz))
    if not loads:
        return "no loadable segment (PT_LOAD)"
    if len(dynamic) != 1:
        return f"{len(dynamic)} dynamic segments (PT_DYNAMIC), expected 1"
    why = _dynamic(data, loads, *dynamic[0])
    if why is not None:
        return why
    if shoff and shoff + max(shnum, 1) * _SHDR.size > size:
        return (f"its section header table (bytes {shoff} to {shoff + max(shnum, 1) * _SHDR.size}) ends past "
                f"the end of the file ({size} bytes)")
    for i in range(shnum if shoff else 0):
        _, sh_type, _, _, offset, sh_size, *_ = _SHDR.unpack_from(data, shoff + i * _SHDR.size)
        if sh_type != SHT_NOBITS and offset + sh_size > size:
            return f"section {i} ends at byte {offset + sh_size}, past the end of the file ({size} bytes)"
    return None


def _dynamic(data: bytes, loads: list[tuple[int, int, int]], index: int, offset: int, filesz: int) -> str | None:
    """What is wrong with the dynamic section (segment ``index``), or None."""
    if not any(o <= offset and offset + filesz <= o + n for o, _, n in loads):
        return f"the dynamic segment {index} lies outside the file part of every loaded segment"
    entries = {}
    for at in range(offset, offset + filesz - _DYN.size + 1, _DYN.size):
        tag, value = _DYN.unpack_from(data, at)
        if tag == DT_NULL:
            break
        entries.setdefault(tag, value)
    else:
        return f"the dynamic section (segment {index}) has no DT_NULL entry inside its {filesz} bytes"
    for tag, (name, size_tag) in _TABLES.items():
        if tag not in entries:
            continue
        start, length = entries[tag], entries.get(size_tag, 1) if size_tag is not None else 1
        if not any(v <= start and start + length <= v + n for _, v, n in loads):
            return (f"its dynamic section's {name} (address {start:#x}, {length} bytes) lies outside the file "
                    "part of every loaded segment")
    return None


__all__ = ["MACHINES", "defect", "host"]
