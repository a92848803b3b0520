"""The lab page's words: the HTML of the results it shows (the ranking as it forms, the
evidence, the asking's steps) and the sentence that says why a button cannot act. Plain
functions of the station's state and the jobs' results; the page (:mod:`labrig.lab.page`)
places them."""
from __future__ import annotations

import html

from labrig.lab.station import Station


def forming_html(stream: list[dict]) -> str:
    """The rungs the search has climbed so far, and the candidates of the round under
    way (re-fitted since the last rung), best first, with their held-out error once
    known."""
    stream = [e for e in stream if e["kind"] in ("rung", "fitted", "validated")]
    rungs = [e for e in stream if e["kind"] == "rung"]
    last = max((i for i, e in enumerate(stream) if e["kind"] == "rung"), default=-1)
    seen: dict = {}
    for e in stream[last + 1:]:
        row = seen.setdefault(e["label"], {"rmse": e["rmse_over_noise"], "cv": None})
        if e["kind"] == "validated":
            row["cv"] = e["cross_validated"]
    html = ""
    if rungs:
        rows = "".join(f"<tr><td>{esc(e['label'])}</td><td>{_num(e['rmse_over_noise'])}</td>"
                       f"<td>{_num(e['cross_validated'])}</td></tr>" for e in rungs)
        html = ("<p><b>the search so far</b></p><table class='lab-table'><tr><th>rung</th>"
                f"<th>rmse/noise</th><th>cross-validated</th></tr>{rows}</table>")
    if seen:
        rows = "".join(f"<tr><td>{esc(k)}</td><td>{_num(v['rmse'])}</td>"
                       f"<td>{_num(v['cv'])}</td></tr>"
                       for k, v in sorted(seen.items(), key=lambda kv: kv[1]["rmse"]))
        html += (f"<p><b>the ranking as it forms ({len(seen)} re-fitted)</b></p>"
                 "<table class='lab-table lab-forming-ranking'><tr><th>candidate</th>"
                 f"<th>rmse/noise</th><th>cross-validated</th></tr>{rows}</table>")
    return html


def _num(x) -> str:
    return "…" if x is None else f"{x:.2f}"


def set_text(pane, text: str) -> None:
    """A pane's text, sent to the browser only when it changed (ten refreshes a second)."""
    if pane.object != text:
        pane.object = text


def asking_html(st: Station) -> str:
    """Asking until sure: each step's verdict as it comes (the job's lines), then the
    result; a Stop ends it with every finished step kept."""
    if st.worker.busy and st.worker.name == "ask":
        steps = [line for line in st.log if line.startswith("step ")]
        live = " (the rig is playing it: Stop keeps every finished step)" if st.sweeping else ""
        return ("<p><b>asking the rig until sure</b>" + live + "</p><pre>"
                + esc("\n".join(steps[-8:]) or "the one-shot plan first, for comparison")
                + "</pre>")
    if st.asking:
        return ("<p><b>asked until sure:</b></p><pre style=\"white-space:pre-wrap\">"
                + esc(st.asking["text"]) + "</pre>")
    return ""


def why_not(st: Station, pairs: bool) -> str:
    """Why the Ask tab's next button cannot act yet, in a sentence ('' when it can)."""
    if st.diagnosis is None:
        return "Fit and diagnose a model first (The loop): the pairs to ask about come from it."
    if not pairs:
        return ("The diagnosis has no two explanations that fit equally well: nothing to ask "
                "the rig.")
    if st.proposal is None:
        return ""
    if st.proposal.get("plan") is None:
        return ("No input within the budget separates the pair, so there is nothing to play "
                "(the proposal says what would).")
    if st.prediction is None:
        return "Record which explanation you expect, and why, to play the experiment."
    return ""


def esc(text: str) -> str:
    return html.escape(text)


def evidence_html(d: dict) -> str:
    """The catalogue as diagnose ranked it, with its evidence and physics sentence."""
    head = ("<tr><th>effect</th><th>rmse/noise</th><th>dBIC</th><th>cross-validated</th>"
            "<th>folds</th><th>supported</th><th>confusable with</th><th>what it is</th></tr>")
    rows = []
    for r in d["rows"]:
        cv = "-" if r["cross_validated"] is None else f"{r['cross_validated']:.2f}"
        sup = ("yes" if r["supported"] else "no") + (" (at bound)" if r["at_bound"] else "") \
            + (" (screened out)" if r.get("screened") else "")
        rows.append(f"<tr><td><b>{esc(r.get('label', r['effect']))}</b></td><td>{r['rmse_over_noise']:.2f}</td>"
                    f"<td>{r['delta_bic']:.0f}</td><td>{cv}</td><td>{r['folds']}</td>"
                    f"<td>{sup}</td><td>{esc(', '.join(r['confusable_with']))}</td>"
                    f"<td>{esc(r['physics'])}</td></tr>")
    rec = d["recommendation"] or "none"
    return (f"<p><b>recommendation: {esc(rec)}</b></p><table class='lab-table'>{head}"
            + "".join(rows) + f"</table><p>{esc(d['verdict'])}</p>")
