#!/usr/bin/env python3
"""Counts test cases in the JUnit XML files under a results folder (gtest, rostest, our own
scripts) and prints the failures and a closing line "N passed, N failed[, N skipped]".
Exit status 1 when anything failed or nothing ran at all."""
import pathlib
import sys
import xml.etree.ElementTree as ET


def main() -> int:
    root = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "build/test_results")
    passed = failed = skipped = 0
    failures = []
    for xml in sorted(root.rglob("*.xml")):
        try:
            tree = ET.parse(xml)
        except ET.ParseError as e:
            failed += 1
            failures.append(f"{xml}: unreadable result file ({e})")
            continue
        for case in tree.iter("testcase"):
            name = f"{case.get('classname', '')}.{case.get('name', '')}"
            if case.find("failure") is not None or case.find("error") is not None:
                failed += 1
                node = case.find("failure") if case.find("failure") is not None else case.find("error")
                msg = (node.get("message") or node.text or "").strip().splitlines()
                failures.append(f"{xml.name}: {name}: {msg[0] if msg else ''}")
            elif case.find("skipped") is not None or case.get("status") == "notrun":
                skipped += 1
            else:
                passed += 1
    for f in failures:
        print("FAILED", f)
    line = f"{passed} passed, {failed} failed"
    if skipped:
        line += f", {skipped} skipped"
    print(line)
    return 1 if failed or passed == 0 else 0


if __name__ == "__main__":
    sys.exit(main())
