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


#: what the overlay's speed figure draws (its Bokeh models, by name): the time in view
#: (start, end), the number of points drawn, the time between two of them and the sum
#: of the model's drawn values
#: whether that figure is in the page yet
DRAWN_READY = r"""() => !!(window.Bokeh && Bokeh.documents.find(
  d => d.get_model_by_name("run-view-speed") && d.get_model_by_name("run-view-time")))"""
DRAWN = r"""() => { const doc = Bokeh.documents.find(d => d.get_model_by_name("run-view-speed"));
  const src = doc.get_model_by_name("run-view-speed"), x = doc.get_model_by_name("run-view-time");
  const col = k => src.data.get ? src.data.get(k) : src.data[k];
  const t = col("t"), m = col("model");
  return [x.start, x.end, t.length, t[1] - t[0], Array.from(m).reduce((a, b) => a + b, 0)]; }"""


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now (the system picks it)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
