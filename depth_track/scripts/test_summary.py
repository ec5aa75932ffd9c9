#!/usr/bin/env python3
"""Counts the test cases in the JUnit XML files under a results folder (gtest, rostest, our own
scripts), prints the failures and the skips with their reasons, and ends with the line
"N passed, N failed[, N skipped]". Exit status 1 when anything failed or nothing ran at all.

    test_summary.py [RESULTS_DIR] [--source ROOT] [--exit-codes CTEST_JUNIT]

Three things are checked besides the cases themselves:
  - every test the source tree declares produced a result file (EXPECTED below, derived from the
    same file globs the CMakeLists use): a test whose registration vanished (a missing package, an
    `if(TARGET ...)` that was false) is a failure, not silence;
  - each rostest case is counted once: the wrapper file (rostest-*.xml) holds one case per test
    node that only repeats the node's own result file (rosunit-*.xml); the wrapper's case counts
    only when it failed and the node's own file does not already carry a failure (the node
    crashed, hung or wrote nothing);
  - with --exit-codes (the JUnit file of `ctest --output-junit`), a test command that exited
    non-zero counts as a failure even when its XML says every case passed (a binary that writes
    its results and then crashes at teardown).
"""
import argparse
import glob
import os
import pathlib
import re
import sys
import xml.etree.ElementTree as ET

# (source files, result files they must produce). {pkg} = first folder of the source path,
# {stem} = its file name without extension. Keep these in step with the CMakeLists' globs:
#   depth_track/src/core/CMakeLists.txt   one dt_<stem> per test/core/test_*.cpp
#   depth_track/CMakeLists.txt            dt_<stem> per test/tools/test_*.cpp, test/ros gtests
#   rig_drivers/src/CMakeLists.txt        one rig_<stem> per test/<part>/test_*.cpp
#   add_rostest(test/ros/<stem>.test)     rostest-test_ros_<stem>.xml
EXPECTED = [
    ("depth_track/test/core/test_*.cpp", "depth_track/gtest-dt_{stem}.xml"),
    ("depth_track/test/tools/test_*.cpp", "depth_track/gtest-dt_{stem}.xml"),
    ("rig_drivers/test/*/test_*.cpp", "rig_drivers/gtest-rig_{stem}.xml"),
    ("*/test/ros/*.test", "{pkg}/rostest-test_ros_{stem}.xml"),
    # a test/ros source without a launch file of its own name is a plain gtest (dt_test_ros_*)
    ("*/test/ros/test_*.cpp", "{pkg}/gtest-*{name}*.xml"),
    ("rig_drivers/test/protocol/fuzz_codec.cpp", "rig_drivers/fuzz-rig.xml"),
]


def is_rostest_node(src: pathlib.Path) -> bool:
    """True when a launch file beside test_<name>.cpp runs it (type="<pkg>_test_<name>")."""
    name = re.escape(src.stem[len("test_"):])
    node = re.compile(r'type="[A-Za-z]+_test_(ros_)?' + name + '"')
    return any(node.search(t.read_text(errors="replace")) for t in src.parent.glob("*.test"))


def expected_results(source: pathlib.Path):
    """(source file, result pattern) for every test the tree declares."""
    out = []
    for src_glob, pattern in EXPECTED:
        for f in sorted(source.glob(src_glob)):
            rel = f.relative_to(source)
            if rel.parts[-2] == "ros" and "/test/*/" in src_glob:
                continue  # test/ros holds the ROS tests, matched by the rules below
            stem = f.stem
            if "{name}" in pattern and is_rostest_node(f):
                continue  # the source of a rostest node, expected through its launch file
            out.append((str(rel), pattern.format(pkg=rel.parts[0], stem=stem,
                                                 name=stem[len("test_"):])))
    return out


def message_of(node) -> str:
    """A result message on one line; gtest's leading "file:line" line is kept as a prefix."""
    lines = [l.strip() for l in (node.get("message") or node.text or "").strip().splitlines()]
    text = " ".join(l for l in lines if l)
    return text if len(text) <= 400 else text[:400] + " ..."


def case_state(case):
    """'failed' (with its message), 'skipped' (with its reason) or 'passed'."""
    for tag in ("failure", "error"):
        node = case.find(tag)
        if node is not None:
            return "failed", message_of(node)
    node = case.find("skipped")
    if node is not None or case.get("status") == "notrun" or case.get("result") == "skipped":
        return "skipped", message_of(node) if node is not None else ""
    return "passed", ""


def parse(xml):
    try:
        return ET.parse(xml), None
    except ET.ParseError as e:
        return None, str(e)


def has_failure(xml: pathlib.Path) -> bool:
    tree, err = parse(xml)
    if tree is None:
        return True
    return any(case_state(c)[0] == "failed" for c in tree.iter("testcase"))


def result_file_of_ctest(name: str):
    """ctest test name (catkin: _ctest_<pkg>_<type>_<target>) -> result file relative path."""
    m = re.match(r"_ctest_(depth_track|rig_drivers|rig_msgs)_(gtest|rostest|fuzz)_(.+)$", name)
    if not m:
        return None
    pkg, kind, target = m.groups()
    if kind == "gtest":
        return f"{pkg}/gtest-{target}.xml"
    if kind == "rostest":  # target = test_ros_<stem>.test
        return f"{pkg}/rostest-{target[:-len('.test')] if target.endswith('.test') else target}.xml"
    return f"{pkg}/fuzz-rig.xml" if target == "codec_firmware" else None


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("results", nargs="?", default="build/test_results")
    ap.add_argument("--source", default=str(pathlib.Path(__file__).resolve().parents[2]),
                    help="repository root whose test sources say which results must exist")
    ap.add_argument("--exit-codes", help="JUnit file written by ctest --output-junit")
    args = ap.parse_args()
    root = pathlib.Path(args.results)
    passed = failed = skipped = 0
    failures, skips = [], []

    for xml in sorted(root.rglob("*.xml")):
        tree, err = parse(xml)
        if tree is None:
            failed += 1
            failures.append(f"{xml}: unreadable result file ({err})")
            continue
        for case in tree.iter("testcase"):
            name = f"{case.get('classname', '')}.{case.get('name', '')}"
            state, msg = case_state(case)
            if case.get("classname") == "rostest.runner.RosTest":
                # the node's own file: rosunit-<test-name>.xml (wrapper case name "test<name>")
                node_file = xml.parent / f"rosunit-{case.get('name', '')[len('test'):]}.xml"
                if state != "failed" or (node_file.exists() and has_failure(node_file)):
                    continue
                msg = msg or "the test node failed without a result of its own"
            if state == "failed":
                failed += 1
                failures.append(f"{xml.name}: {name}: {msg}")
            elif state == "skipped":
                skipped += 1
                skips.append(f"{xml.name}: {name}: {msg}" if msg else f"{xml.name}: {name}")
            else:
                passed += 1

    source = pathlib.Path(args.source)
    for src, pattern in expected_results(source):
        missing_pattern = str(pathlib.Path(pattern).parent / ("MISSING-" + pathlib.Path(pattern).name))
        if glob.glob(str(root / pattern)) or glob.glob(str(root / missing_pattern)):
            continue  # a MISSING-* placeholder is already counted as a failed case above
        failed += 1
        failures.append(f"{pattern}: no result file for {src} (test not declared, not built or "
                        f"not run)")

    if args.exit_codes:
        tree, err = parse(args.exit_codes) if os.path.exists(args.exit_codes) else (None, "missing")
        if tree is None:
            failed += 1
            failures.append(f"{args.exit_codes}: ctest exit codes unreadable ({err})")
        else:
            for case in tree.iter("testcase"):
                if case.get("status") != "fail" and case.find("failure") is None:
                    continue
                res = result_file_of_ctest(case.get("name", ""))
                if res is None or not (root / res).exists() or has_failure(root / res):
                    continue  # its failing cases (or MISSING-* placeholder) are counted already
                failed += 1
                failures.append(f"{res}: {case.get('name')} exited with failure although its "
                                f"results say passed (crash after writing them?)")

    for s in skips:
        print("SKIPPED", s)
    for f in failures:
        print("FAILED", f)
    line = f"{passed} passed, {failed} failed"
    if skipped:
        line += f", {skipped} skipped"
    print(line)
    return 1 if failed or passed == 0 else 0


if __name__ == "__main__":
    sys.exit(main())
