"""The one reader of JSON input files: what it refuses before a value reaches the code that checks it."""

from __future__ import annotations

import os
import threading

import pytest

from driveopt.errors import DriveoptError
from driveopt.jsonfile import MAX_BYTES, MAX_DEPTH, JSONFileError, nesting_depth, parse_json, read_json


def _file(tmp_path, content: str | bytes):
    path = tmp_path / "input.json"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    return path


def test_a_plain_file_reads_as_json(tmp_path):
    path = _file(tmp_path, '{"a": [1, -2.5e3, "x]]{{", true, null], "b": {"c": "\\ud83d\\ude00"}}')
    assert read_json(path) == {"a": [1, -2500.0, "x]]{{", True, None], "b": {"c": "\U0001F600"}}


@pytest.mark.parametrize(
    "content, needle",
    [
        ('{"x": ' + "1" * 400 + "}", "has 400 characters"),
        ('{"x": 1' + "0" * 400 + ".5}", "has 403 characters"),
        ('{"x": 1e400}', "beyond the range of a float"),
        ('{"x": -1e400}', "beyond the range of a float"),
        ('{"x": NaN}', "NaN is not a JSON number"),
        ('{"x": Infinity}', "Infinity is not a JSON number"),
        ('{"x": -Infinity}', "-Infinity is not a JSON number"),
        ("[" * 100_000 + "]" * 100_000, f"nested deeper than {MAX_DEPTH} levels"),
        ('{"a": ' * 100_000 + "1" + "}" * 100_000, f"nested deeper than {MAX_DEPTH} levels"),
        ('{"name": "\\ud800"}', "not valid Unicode"),
        ('{"\\udfff": 1}', "not valid Unicode"),
        ('[["\\ud800x"]]', "not valid Unicode"),
        ('{"a": 1, "a": 2}', "key 'a' appears twice"),
        ('{"a": }', "not valid JSON (Expecting value at line 1 column 7)"),
        (b'{"a": "\xff"}', "not UTF-8 text"),
    ],
)
def test_content_beyond_the_limits_is_a_one_line_error_naming_the_file(tmp_path, content, needle):
    path = _file(tmp_path, content)
    with pytest.raises(JSONFileError) as info:
        read_json(path, "problem file")
    message = str(info.value)
    assert needle in message and message.startswith(f"problem file {path}: ") and "\n" not in message


def test_brackets_inside_strings_do_not_count_as_nesting():
    text = '{"a": "' + "[" * 1000 + '\\"' + "{" * 1000 + '"}'
    assert nesting_depth(text) == 1
    assert parse_json(text)["a"].startswith("[[")


def test_the_depth_is_counted_without_recursion():
    assert nesting_depth("[" * 1_000_000) == 1_000_000
    assert nesting_depth('[{"a": [1, {"b": []}]}, []]') == 5


def test_a_missing_file_says_no_such_file(tmp_path):
    with pytest.raises(JSONFileError, match=r"config .*nope\.json: no such file$"):
        read_json(tmp_path / "nope.json", "config")


def test_a_directory_is_refused(tmp_path):
    with pytest.raises(JSONFileError, match="not a regular file .a directory."):
        read_json(tmp_path)


def test_a_device_is_refused_without_reading_it():
    with pytest.raises(JSONFileError, match="not a regular file .a character device."):
        read_json("/dev/zero")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="FIFOs are POSIX")
def test_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    outcome = []
    reader = threading.Thread(target=lambda: outcome.append(_error_of(lambda: read_json(fifo))), daemon=True)
    reader.start()
    reader.join(timeout=10)
    if reader.is_alive():  # free the blocked reader, then fail
        with open(fifo, "wb"):
            pass
        pytest.fail("reading a FIFO blocked")
    assert "not a regular file (a FIFO)" in outcome[0]


def _error_of(call) -> str:
    try:
        call()
    except DriveoptError as exc:
        return str(exc)
    return "no error"


def test_a_file_over_the_size_limit_is_refused_before_parsing(tmp_path):
    path = tmp_path / "big.json"
    with open(path, "wb") as f:
        f.truncate(MAX_BYTES + 1)  # sparse: no disk space used
    with pytest.raises(JSONFileError, match="more than the 10 MB"):
        read_json(path)


def test_the_caller_chooses_the_error_type(tmp_path):
    class ProblemLikeError(DriveoptError):
        pass

    with pytest.raises(ProblemLikeError, match="no such file"):
        read_json(tmp_path / "nope.json", "problem file", ProblemLikeError)
