"""Worst-case stack of a call chain from GCC's call graphs (``-fcallgraph-info=su``).

Reads the ``.ci`` files given, adds each function's static frame along the deepest path
from ``main`` (recursion is reported, not followed; calls through pointers and into
libraries without a ``.ci`` count 0) and prints one line:
``stack: 520 bytes worst case (main 168 -> arva_decoder_next 288 -> ...)``.
Usage: ``python3 stack_usage.py build/*.ci``.
"""

import re
import sys

NODE = re.compile(r'node: \{ title: "([^"]+)" label: "([^"\\]+)\\n[^"]*?(\d+) bytes')
EDGE = re.compile(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"')


def main(paths):
    frames, calls, names = {}, {}, {}
    for path in paths:
        text = open(path).read()
        for title, name, size in NODE.findall(text):
            frames[title] = int(size)
            names[title] = name
        for src, dst in EDGE.findall(text):
            calls.setdefault(src, []).append(dst)
    by_name = {names[t]: t for t in frames}

    def deepest(node, path):
        if node in path:
            return 0, [names.get(node, node) + " (recursion)"]
        best, chain = 0, []
        for callee in calls.get(node, []):
            callee = callee if callee in frames else by_name.get(callee.rsplit(":", 1)[-1], callee)
            size, sub = deepest(callee, path + (node,))
            if size > best:
                best, chain = size, sub
        own = frames.get(node, 0)
        return own + best, [f"{names.get(node, node)} {own}"] + chain

    root = by_name.get("main")
    if root is None:
        print("stack: no main in the call graphs", file=sys.stderr)
        return 1
    total, chain = deepest(root, ())
    print(f"stack: {total} bytes worst case ({' -> '.join(chain)})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
