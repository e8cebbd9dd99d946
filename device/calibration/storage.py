"""Reading OpenCV FileStorage (YAML/XML) and ROS camera_info YAML files within bounds, for the calibration readers.

A calibration file is a few kilobytes of small matrices, so anything else is refused before OpenCV's parser
sees it, with a :class:`CalibrationError` naming the file: more than ``MAX_FILE_BYTES``, binary content (a
video given as ``calib=``), flow nesting deeper than ``MAX_DEPTH``, block indentation beyond
``MAX_INDENT`` columns, an XML DTD or entity. Steps of :func:`read_storage`: those checks on the bytes, then
``cv2.FileStorage`` (its own failures, ``cv2.error`` or ``SystemError``, become CalibrationError), then the
top-level nodes to Python values reading at most ``MAX_DEPTH`` levels and ``MAX_ITEMS`` items per sequence
(each item read once: linear time). ``!!opencv-matrix`` nodes are rebuilt from their ``rows``, ``cols``
and ``data`` after checking them, so a matrix claiming 10^8 rows allocates nothing.
"""

from __future__ import annotations

import io
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from device.errors import CalibrationError

MAX_FILE_BYTES = 1 << 20
MAX_DEPTH = 6  # nesting of maps and sequences (a ROS matrix is a map holding a list: depth 2)
MAX_INDENT = 128  # columns of block indentation in YAML
MAX_ITEMS = 256  # items per sequence (the largest calibration field, a 3x4 projection, has 12)
_QUOTED = re.compile(rb'"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'')
_COMMENT = re.compile(rb"#[^\n]*")
_INDENT = re.compile(rb"^[ \t]*", re.M)


def _check_bytes(path: Path, data: bytes) -> None:
    if not data.strip():
        raise CalibrationError(f"{path} is empty; give a calibration file (project .json, OpenCV .yaml/.xml, ROS .yaml)")
    if b"\x00" in data:
        raise CalibrationError(f"{path} is a binary file, not a YAML/XML calibration; check the calib= path")
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CalibrationError(f"{path} is not UTF-8 text (byte {exc.start}); a YAML/XML calibration is text") from None
    if data.lstrip().startswith(b"<"):
        _check_xml(path, data)
        return
    text = _COMMENT.sub(b"", _QUOTED.sub(b'""', data))
    b = np.frombuffer(text, np.uint8)
    step = np.isin(b, np.frombuffer(b"[{", np.uint8)).astype(np.int64) - np.isin(b, np.frombuffer(b"]}", np.uint8))
    depth = int(np.cumsum(step).max(initial=0))
    if depth > MAX_DEPTH:
        raise CalibrationError(f"{path}: lists or maps nested {depth} deep; a calibration file nests at most {MAX_DEPTH}")
    indent = max((len(m.group(0)) for m in _INDENT.finditer(text)), default=0)
    if indent > MAX_INDENT:
        raise CalibrationError(f"{path}: a line indented {indent} columns; a calibration file needs at most {MAX_INDENT}")


def _check_xml(path: Path, data: bytes) -> None:
    if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
        raise CalibrationError(f"{path}: an XML DTD or entity; OpenCV calibration XML has none")
    depth = deepest = 0
    try:
        for event, _ in ET.iterparse(io.BytesIO(data), events=("start", "end")):
            depth += 1 if event == "start" else -1
            deepest = max(deepest, depth)
            if deepest > MAX_DEPTH + 1:  # +1: the <opencv_storage> root
                raise CalibrationError(f"{path}: XML elements nested more than {MAX_DEPTH} deep; not a calibration file")
    except ET.ParseError as exc:
        raise CalibrationError(f"{path} is not well-formed XML ({exc})") from None


def read_storage(path: Path) -> dict[str, Any]:
    """Top-level nodes of a FileStorage file (YAML, XML, ROS YAML) as Python values: numbers as float,
    strings, lists, dicts, matrices as float64 arrays. Steps and bounds: module docstring."""
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise CalibrationError(f"{path} has {size} bytes; a calibration file has a few thousand (at most {MAX_FILE_BYTES})")
        data = path.read_bytes()
    except OSError as exc:
        raise CalibrationError(f"cannot read {path} ({exc.strerror or exc})") from exc
    _check_bytes(path, data)
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_FORMAT_AUTO)
    except (cv2.error, SystemError) as exc:  # OpenCV's parser reports some errors as SystemError
        raise CalibrationError(f"{path} is not an OpenCV FileStorage / ROS YAML file ({_reason(exc)})") from None
    try:
        if not fs.isOpened():
            raise CalibrationError(f"cannot read {path} as OpenCV YAML/XML")
        root = fs.root()
        if not root.isMap():
            raise CalibrationError(f"{path}: the top level is not a map of named fields (K1, D1, ... or camera_matrix, ...)")
        if root.size() > MAX_ITEMS:  # before keys(): looking each of many names up costs quadratic time
            raise CalibrationError(f"{path} has {root.size()} top-level fields; a calibration file has a few dozen")
        return {name: _value(root.getNode(name), path, name, 1) for name in root.keys()}
    except (cv2.error, SystemError) as exc:
        raise CalibrationError(f"{path} cannot be read as OpenCV YAML/XML ({_reason(exc)})") from None
    finally:
        fs.release()


def _reason(exc: BaseException) -> str:
    return str(getattr(exc, "err", "") or exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__


def _value(node: cv2.FileNode, path: Path, name: str, depth: int) -> Any:
    if depth > MAX_DEPTH:
        raise CalibrationError(f"{path}: field {name} nests deeper than {MAX_DEPTH} levels; not a calibration file")
    if node.isMap():
        keys = node.keys()
        if len(keys) > MAX_ITEMS:
            raise CalibrationError(f"{path}: field {name} has {len(keys)} entries; a calibration field has at most {MAX_ITEMS}")
        if {"rows", "cols", "data"} <= set(keys) and not node.getNode("dt").isNone():
            return _opencv_matrix(node, path, name)
        return {k: _value(node.getNode(k), path, f"{name}.{k}", depth + 1) for k in keys}
    if node.isSeq():
        n = node.size()
        if n > MAX_ITEMS:
            raise CalibrationError(f"{path}: field {name} has {n} items; a calibration field has at most {MAX_ITEMS}")
        return [_value(node.at(i), path, f"{name}[{i}]", depth + 1) for i in range(n)]
    if node.isString():
        return node.string()
    if node.isInt() or node.isReal():
        return node.real()
    return None


def _opencv_matrix(node: cv2.FileNode, path: Path, name: str) -> np.ndarray:
    """An ``!!opencv-matrix`` from its fields, checked before anything is allocated."""
    dims = {}
    for key in ("rows", "cols"):
        sub = node.getNode(key)
        v = sub.real() if sub.isInt() or sub.isReal() else None
        if v is None or not (1 <= v <= MAX_ITEMS) or v != int(v):
            raise CalibrationError(f"{path}: field {name}.{key} must be a whole number 1..{MAX_ITEMS}, got "
                                   f"{sub.string() if sub.isString() else v!r}")
        dims[key] = int(v)
    data = node.getNode("data")
    count = data.size() if data.isSeq() else -1
    if count != dims["rows"] * dims["cols"]:
        raise CalibrationError(f"{path}: field {name} says {dims['rows']}x{dims['cols']} but its data holds "
                               f"{max(count, 0)} numbers; the matrix is damaged")
    values = [data.at(i) for i in range(count)]
    if not all(v.isInt() or v.isReal() for v in values):
        raise CalibrationError(f"{path}: field {name}.data must hold numbers only")
    return np.array([v.real() for v in values], np.float64).reshape(dims["rows"], dims["cols"])
