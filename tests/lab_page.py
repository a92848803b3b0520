"""What the lab page's browser test (tests/test_lab.py) and its benchmark
(benchmarks/bench_lab.py) both need: a port to serve `labrig lab` on, and the words an
element of the page shows."""
from __future__ import annotations

import socket

#: the words of an element and its shadow root, text nodes joined by spaces (no styles)
WORDS = r"""e => { const out = [];
  const walk = n => { if (n.nodeType === 3) out.push(n.textContent);
    else if (n.nodeName !== 'STYLE' && n.nodeName !== 'SCRIPT') {
      if (n.shadowRoot) walk(n.shadowRoot); n.childNodes.forEach(walk); } };
  walk(e); return out.join(' ').replace(/\s+/g, ' '); }"""


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now (the system picks it)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
