"""The benchmark report: Markdown tables laid out like the paper's, PNG plots, raw numbers as JSON.

`write(results, out)` takes the dictionary tools/bench.py builds. Every table names the data it
ran on and the parts that were simulated; the claims section compares our numbers with the
paper's qualitative claims and says plainly where they disagree. Files are written to a staging
folder and moved into place one by one, so each file in `out` is whole.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from clipclique.benchmark import calibration, paper_tables  # noqa: E402
from clipclique.localization.results import json_safe  # noqa: E402

PAPER_LANDMARKS_AT_1S = 410  # the paper: about 410 landmarks localized within 1 s, growing quadratically
CLAIM_SCALE = f"About {PAPER_LANDMARKS_AT_1S} landmarks within 1 s, quadratic growth"
LITERAL = "Literal reference"
NOT_BASELINES = ("CLIP-Clique (paper)", LITERAL)  # our own variants, not the paper's baselines
PAPER_SIMILARITY = {"clip": 0.4, "sh": 0.8}  # the paper: CLIP similarities near 0.4 where SH reaches ~0.8
ABLATIONS = {
    "fixes": "Real-scene fixes (beyond the paper; each switched off alone)",
    "descriptors": "Descriptors (similarity.descriptor)",
    "inliers": "Inlier extraction (inliers.method)",
    "weights": "Pose weights (pose.weights)",
    "matching": "Initial matching (matching.strategy)",
}
COLUMNS: list[tuple[str, str, Callable[[float], str]]] = [
    ("Precision", "precision", lambda v: f"{v:.2f}"),
    ("Recall", "recall", lambda v: f"{v:.2f}"),
    ("TE [m]", "te_median_m", lambda v: f"{v:.2f}"),
    ("RE [deg]", "re_median_deg", lambda v: f"{v:.1f}"),
    ("Top-1 [%]", "success@1", lambda v: f"{100 * v:.1f}"),
    ("Top-3 [%]", "success@3", lambda v: f"{100 * v:.1f}"),
    ("Top-5 [%]", "success@5", lambda v: f"{100 * v:.1f}"),
    ("Time [ms]", "time_ms_median", lambda v: f"{v:.1f}"),
]

def write(results: dict[str, Any], out: Path) -> None:
    """report.md, methods.png, alpha.png, scalability.png, reliability.png and results.json into `out`."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".bench-", dir=out))
    try:
        plots = [name for name, plot in (("methods.png", plot_methods), ("alpha.png", plot_alpha),
                                         ("scalability.png", plot_scalability), ("reliability.png", plot_calibration))
                 if plot(results, staging / name)]
        (staging / "results.json").write_text(json.dumps(json_safe(results), indent=1, allow_nan=False))
        (staging / "report.md").write_text(markdown(results, plots))
        for path in staging.iterdir():
            os.replace(path, out / path.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


# ---------------------------------------------------------------------------------------------- text


def markdown(results: dict[str, Any], plots: list[str]) -> str:
    sections = [header(results), summary_section(results), data_section(results), table_one(results),
                ablations(results),
                alpha_section(results, "alpha.png" in plots), scalability_section(results, "scalability.png" in plots),
                gpu_section(results), verification_section(results, "reliability.png" in plots),
                claims_section(results)]
    if "methods.png" in plots:
        sections.insert(4, "![Top-k success of the four methods](methods.png)\n")
    return "\n".join(sections)


def header(results: dict[str, Any]) -> str:
    host = results["machine"]
    quick = (" **Quick mode: a handful of frames per sequence; numbers are a "
             "smoke test, not results.**") if results["quick"] else ""
    return (
        "# CLIP-Clique benchmark: the paper's experiments on the available sequences\n\n"
        f"Generated {results['created']} by `{results['command']}` (commit {host['commit']}) on "
        f"{host['cores']} CPU cores ({host['cpu']}, Python {host['python']}); the whole suite took "
        f"**{results['wall_time_s']:.0f} s**.{quick} Timings come from a shared machine and are noisy; numpy's "
        f"OpenBLAS ran with {host['openblas_threads'] or 'its default number of'} thread(s) (OPENBLAS_NUM_THREADS): "
        "a query's matrices are small, and BLAS threads waiting for a busy core added up to ~10 ms per query in our "
        "runs.\n\n"
        "Each sequence's frames went through the detector, the observation fit and the encoder once; every "
        "configuration then localized the same cached observations. Stochastic configurations (RANSAC, PROSAC, "
        "X-View's random walks; marked †) ran with three seeds: tables give the best seed, as the paper does, "
        "and the Top-1 range over the seeds. With seed 0 the cached path gives exactly the numbers of "
        "`clipclique-loc run` (tests/e2e/test_bench.py checks it).\n\n"
        "Columns: precision and recall of the top-1 hypothesis's correspondences (by object id); TE/RE: median "
        "translation/rotation error of the top-1 pose over frames with a pose; Top-k: frames with a pose within "
        "1 m among the k best (frames without a pose count as failures); Time: median matching + inliers + pose "
        "per query; Pose (Table I): frames with any pose. The paper's published numbers (real ScanNet and TUM "
        "sequences, real CLIP and YOLO) stand above each of our tables; they are not the same data.\n"
    )


def summary_section(results: dict[str, Any]) -> str:
    """The headline: CLIP-Clique against the best method per sequence, and how the paper's claims fared."""
    lines = ["## Summary\n"]
    for name, description in results["sequences"].items():
        methods = {r["label"]: r["summary"] for r in rows_of(results, name, "methods") if "summary" in r}
        best = max(methods, key=lambda label: np.nan_to_num(methods[label]["success@1"], nan=-1.0))
        ours = methods.get("CLIP-Clique")
        headline = "CLIP-Clique did not run" if ours is None else (
            f"CLIP-Clique Top-1 {100 * ours['success@1']:.1f}%, Top-5 {100 * ours['success@5']:.1f}%, median TE "
            f"{fmt(ours['te_median_m'], lambda v: f'{v:.2f}')} m, {ours['time_ms_median']:.1f} ms per query; "
            f"best Top-1: {best} {100 * methods[best]['success@1']:.1f}%")
        lines.append(f"- **{name}** ({simulated_tag(description)}): {headline}.")
    verdicts = [v for name in results["sequences"] for _, _, v in sequence_claims(results, name)]
    verdicts += [v for _, _, v in global_claims(results)]
    counts = {word: sum(v.removeprefix("**").startswith(word) for v in verdicts)
              for word in ("agrees", "disagrees", "ties")}
    lines.append(f"- The paper's claims, checked in the last section: agree {counts['agrees']}, "
                 f"**disagree {counts['disagrees']}**, tie {counts['ties']} (of {len(verdicts)} checks).")
    return "\n".join(lines) + "\n"


def provenance(description: dict[str, Any]) -> str:
    """One line: what the data is and which parts were simulated."""
    data = (f"synthetic {description['kind']}-layout demo scene (procedural, ray-cast)" if description["synthetic"]
            else f"real {description['kind']} data")
    simulated = [f"{role} ({part['name']})" for role, part in (("detector", description["detector"]),
                                                               ("CLIP", description["encoder"]))
                 if part and part["simulated"]]
    clip = "no CLIP (Semantic Histograms only)" if description["encoder"] is None else ""
    parts = "; ".join(filter(None, [data, f"simulated: {', '.join(simulated)}" if simulated else "nothing simulated",
                                    clip]))
    return f"{description['sequence']}: {description['frames']} frames, {description['landmarks']} landmarks; {parts}"


def data_section(results: dict[str, Any]) -> str:
    lines = ["## Data\n",
             "| Sequence | Data | Frames used | Frames seeing 3+ mapped objects | Landmarks | Detector | CLIP encoder "
             "| Detector / fit / encoder [ms per frame] |", "|---|---|---|---|---|---|---|---|"]
    for name, d in results["sequences"].items():
        data = f"synthetic ({d['kind']} layout)" if d["synthetic"] else f"real ({d['kind']})"
        detector = d["detector"]["name"] + (" **(simulated)**" if d["detector"]["simulated"] else "")
        encoder = ("none" if d["encoder"] is None
                   else d["encoder"]["name"] + (" **(simulated)**" if d["encoder"]["simulated"] else ""))
        stages = " / ".join(f"{d['query_ms'][s]:.1f}" for s in ("detector", "observations", "encoder"))
        lines.append(f"| {name} | {data} | {d['frames']} of {d['sequence_frames']} (stride {d['stride']}) | "
                     f"{d['frames_with_3_mapped']} | {d['landmarks']} ({d['classes']} classes) | {detector} | "
                     f"{encoder} | {stages} |")
    lines += ["",
              "A frame needs at least three observations of mapped objects to fix a correct pose, so the fourth column "
              "bounds, in practice, every method's success rate."]
    if results["skipped_sequences"]:
        lines += ["", "Left out: " + "; ".join(results["skipped_sequences"]) + "."]
    if any(d["synthetic"] for d in results["sequences"].values()):
        lines += ["", "On the demo the detector is the simulated one (ground-truth instances with seeded misses, false "
                  "positives and class confusions) and CLIP is the simulated encoder (text and image embeddings "
                  "of a documented model with known ground truth): their numbers test the pipeline, not CLIP or YOLO."]
    return "\n".join(lines) + "\n"


def rows_of(results: dict[str, Any], name: str, group: str) -> list[dict[str, Any]]:
    return [r for r in results["experiments"][name] if r["group"] == group]


def metric_row(record: dict[str, Any], first: list[str], extra: list[str] = ()) -> str:
    """A table row of the paper's columns, or a row saying why the configuration did not run."""
    label = record["label"] + (" †" if record["stochastic"] else "")
    if "skipped" in record:
        return ("| " + " | ".join([*first, label, f"not run: {record['skipped']}", *[""] * (len(COLUMNS) + len(extra))])
                + " |")
    summary = record["summary"]
    cells = [fmt(summary[key], style) for _, key, style in COLUMNS]
    spread = record.get("spread", {}).get("success@1")
    cells.append(f"{100 * spread[0]:.1f}–{100 * spread[1]:.1f}" if spread else "–")
    return "| " + " | ".join([*first, label, *cells, *extra]) + " |"


def table_head(first: list[str], extra: list[str] = ()) -> str:
    names = [*first, *(title for title, _, _ in COLUMNS), "Top-1 over seeds [%]", *extra]
    return "| " + " | ".join(names) + " |\n|" + "---|" * len(names)


def paper_table(columns: tuple[str, ...], rows: dict[str, dict[str, tuple]], title: str) -> str:
    """The paper's published numbers for one of our tables, every sequence it reports."""
    style = lambda v: "–" if v is None else f"{v:g}"  # noqa: E731
    lines = [f"*{title} (published; {paper_tables.NOTE}):*\n", "| Sequence | Setting | " + " | ".join(columns) + " |",
             "|---|---|" + "---|" * len(columns)]
    for sequence, settings in rows.items():
        lines += [f"| {sequence} | {label} | " + " | ".join(map(style, values)) + " |"
                  for label, values in settings.items()]
    return "\n".join(lines) + "\n"


def table_one(results: dict[str, Any]) -> str:
    parts = ["## Table I: CLIP-Clique and the baselines\n",
             "CLIP-Clique (paper) is the same pipeline with the paper's literal settings (no class term, exact labels, "
             "the rigid 0.3 m test); the literal reference is `clipclique/benchmark/literal_reference.py`, an "
             "independent networkx reading of the paper that shares no code with the library, run on the same cached "
             "observations. The paper's Table I follows ours.\n"]
    for name, description in results["sequences"].items():
        records = rows_of(results, name, "methods")
        parts += [f"**{provenance(description)}.**\n", table_head(["Method"], ["Pose [%]"])]
        parts += [metric_row(r, [], [fmt(r["summary"]["localized"], lambda v: f"{100 * v:.1f}")] if "summary" in r
                             else [""])
                  for r in records]
        parts += ["", "Frames without a pose, by reason: " + "; ".join(
            f"{r['label']}: " + (", ".join(f"{reason} ({count})" for reason, count in r["failures"].items()) or "none")
            for r in records if "failures" in r) + ".", ""]
    parts.append(paper_table(paper_tables.TABLE_ONE_COLUMNS, paper_tables.TABLE_ONE, "The paper's Table I"))
    return "\n".join(parts)


def ablations(results: dict[str, Any]) -> str:
    parts = ["## Ablations (one part of CLIP-Clique changed at a time)\n",
             "Data: " + "; ".join(provenance(d) for d in results["sequences"].values()) + ".\n"]
    for group, title in ABLATIONS.items():
        similarity = group == "descriptors"
        extra = ["Similarity, true pairs: mean / 90th pct.", "Similarity, other pairs: mean"] if similarity else []
        parts += [f"### {title}\n", table_head(["Sequence", "Setting"], extra)]
        for name in results["sequences"]:
            for record in rows_of(results, name, group):
                values = (similarity_cells(record["summary"]) if similarity and "summary" in record
                          else [""] * len(extra))
                parts.append(metric_row(record, [name], values))
        parts.append("")
        if group in paper_tables.ABLATIONS:
            parts.append(paper_table(paper_tables.ABLATION_COLUMNS, paper_tables.ABLATIONS[group], "The paper"))
    return "\n".join(parts)


def similarity_cells(summary: dict[str, float]) -> list[str]:
    two = lambda v: f"{v:.2f}"  # noqa: E731
    return [f"{fmt(summary['similarity_true_mean'], two)} / {fmt(summary['similarity_true_p90'], two)}",
            fmt(summary["similarity_other_mean"], two)]


def alpha_section(results: dict[str, Any], plotted: bool) -> str:
    names = list(results["sequences"])
    lines = ["## Alpha sweep: S = alpha * S_clip + (1 - alpha) * S_sh\n",
             "Top-1 success rate [%] of CLIP-Clique per sequence; the paper's default is alpha = 0.7. Data: "
             + "; ".join(provenance(results["sequences"][n]) for n in names) + ".\n",
             "| alpha | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    per_sequence = {n: rows_of(results, n, "alpha") for n in names}
    for i, alpha in enumerate(r["label"] for r in per_sequence[names[0]]):
        cells = [fmt(per_sequence[n][i].get("summary", {}).get("success@1", math.nan), lambda v: f"{100 * v:.1f}")
                 for n in names]
        lines.append(f"| {alpha} | " + " | ".join(cells) + " |")
    if plotted:
        lines += ["", "![Top-1 success against alpha](alpha.png)"]
    return "\n".join(lines) + "\n"


def scalability_section(results: dict[str, Any], plotted: bool) -> str:
    scene, synthetic = results["scalability"]["scene"], results["scalability"]["synthetic"]
    lines = [
        "## Scalability\n",
        "CLIP-Clique's latency per query as the map grows from 50 to 5,000 landmarks, two ways. Copies are placed as "
        "separate rooms side by side along x, 2 m apart (`clipclique.sim.synthetic.duplicate_rooms`, copy j's object "
        "ids offset so none repeats); copies stacked in one place would make every mix of copies a clique. Since every "
        "copy looks alike, each query's candidates and cliques multiply with the copies.\n",
        f"- **Scene copies (the paper's set-up)**: the {scene['sequence']} map ({scene['room_landmarks']} landmarks; "
        f"{provenance(results['sequences'][scene['sequence']])}) copied round(count / {scene['room_landmarks']}) "
        f"times, queried with {scene['frames_per_count']} of its cached frames (each the fastest of "
        f"{scene['fastest_of']} runs).",
        f"- **Synthetic rooms**: a **simulated** room of {synthetic['room_landmarks']} random labelled ellipsoids "
        "(5 x 5 x 1.5 m, 8 classes, simulated CLIP), queried with 10 of its landmarks plus 2 false detections "
        f"(`clipclique.sim.synthetic`, `tools/bench_core.py`), {synthetic['frames_per_count']} queries per count.\n",
        "Medians over the queries; \"whole query\" adds the query graph, descriptors and similarity to matching + "
        "inliers + pose.\n",
        "| Set-up | Landmarks | Candidates | Cliques | Matching + inliers + pose [ms] | Whole query [ms] | Caps hit |",
        "|---|---|---|---|---|---|---|",
    ]
    for title, data in (("scene copies", scene), ("synthetic rooms", synthetic)):
        lines += [f"| {title} | {r['landmarks']} | {r['candidates']:.0f} | {r['cliques']:.0f} | {r['median_ms']:.2f} | "
                  f"{r['median_total_ms']:.2f} | {r['cap_hits']} |" for r in data["rows"]]
    lines.append("")
    for title, data in (("Scene copies", scene), ("Synthetic rooms", synthetic)):
        lines.append(f"- {title}: fitted growth exponent (log-log slope) **{data['exponent_total']:.2f}** for the "
                     f"whole query ({data['exponent_total_tail']:.2f} over the last three counts), "
                     f"{data['exponent_algorithm']:.2f} for matching + inliers + pose "
                     f"({data['exponent_algorithm_tail']:.2f}); {one_second(data)}.")
    lines += ["",
              f"The paper reports about {PAPER_LANDMARKS_AT_1S} landmarks localized within 1 s, growing quadratically."]
    if scene["exponent_total"] < 1.6:
        lines[-1] += (" Ours grows far more slowly: the compatibility graph is built from a KD-tree's reach instead of "
                      "testing all pairs of candidates (`clipclique/inliers/compatibility.py`), and at these sizes "
                      "fixed per-query costs still weigh heavily.")
    if plotted:
        lines += ["", "![Latency per query against landmark count, log-log](scalability.png)"]
    return "\n".join(lines) + "\n"


def one_second(data: dict[str, Any]) -> str:
    if data["landmarks_at_1s"] is not None:
        return f"a query takes 1 s at about {data['landmarks_at_1s']:,.0f} landmarks"
    largest = data["rows"][-1]
    return (f"{data['ms_at_paper_size']:.1f} ms at {PAPER_LANDMARKS_AT_1S} landmarks and "
            f"{largest['median_total_ms']:.1f} ms at {largest['landmarks']:,}: never near 1 s")


def gpu_section(results: dict[str, Any]) -> str:
    gpu = results["gpu"]
    lines = ["## GPU: end-to-end frames per second\n"]
    if not gpu["ran"]:
        return "\n".join(lines + [f"Not run: {gpu['reason']}. On a machine with CUDA, `make bench` times YOLOv8x-seg "
                                  "and CLIP ViT-L-14 built with random weights (timing only) stage by stage; the "
                                  "CPU timings of the stages that ran here are in the Data table."]) + "\n"
    stages = dict(gpu["stage_ms"])
    total = sum(stages.values())
    lines += [f"On {gpu['device']}, {gpu['frames']} frames of {gpu['sequence']} after {gpu['warmup']} warm-up frames, "
              f"with {' and '.join(gpu['models'])}. **Random weights** serve for timing only: YOLO's output is "
              "discarded and the observation fit and the encoder work on the sequence's own (simulated) detections. "
              "The algorithm row is CLIP-Clique's median matching + inliers + pose from Table I (CPU).\n",
              "| Stage | Median [ms per frame] |", "|---|---|"]
    lines += [f"| {stage} | {ms:.1f} |" for stage, ms in stages.items()]
    lines += [f"| **total** | **{total:.1f}** ({1000 / total:.1f} frames per second) |"]
    return "\n".join(lines) + "\n"


def verification_section(results: dict[str, Any], plotted: bool) -> str:
    """Baselines verified as the paper does against centre distances, re-ranking, and the confidence's calibration."""
    names = list(results["sequences"])
    parts = ["## Verification in the image, re-ranking and confidence\n",
             "RANSAC and PROSAC verify each minimal-set pose as the paper does: the landmarks projected under the pose "
             "(dual-quadric projection of their ellipsoids) against the detection boxes, summed IoU "
             "(`inliers.verification = overlap`, the default). The centre-distance variant scores 3D centre residuals "
             "instead (`inliers.verification = centers`).\n",
             "### Table I baselines: projected overlap (the paper's) against centre distances\n",
             table_head(["Sequence", "Method, verification"])]
    for name in names:
        methods = first_by_method(rows_of(results, name, "methods"))
        for record in rows_of(results, name, "verification"):
            paper = methods[record["method"]]
            parts += [metric_row({**paper, "label": f"{paper['label']}, projected overlap"}, [name]),
                      metric_row(record, [name])]
    parts += ["", "### Re-ranking every method's hypotheses by image verification (`inliers.rerank = verification`)\n",
              "| Sequence | Method | Top-1 as ranked [%] | Top-1 re-ranked [%] | Top-5 [%] |", "|---|---|---|---|---|"]
    percent = lambda v: f"{100 * v:.1f}"  # noqa: E731
    for name in names:
        methods = first_by_method(rows_of(results, name, "methods"))
        for record in rows_of(results, name, "rerank"):
            plain = methods[record["method"]]
            if "summary" not in record or "summary" not in plain:
                parts.append(f"| {name} | {plain['label']} | not run | | |")
                continue
            parts.append(f"| {name} | {plain['label']} | {fmt(plain['summary']['success@1'], percent)} | "
                         f"**{fmt(record['summary']['success@1'], percent)}** | "
                         f"{fmt(record['summary']['success@5'], percent)} |")
    parts += ["",
              "Re-ranking reorders the same top-N poses, so Top-5 does not change; stochastic methods give the best "
              "of three seeds in each column.", "", calibration_text(results.get("calibration"), plotted)]
    return "\n".join(parts) + "\n"


def first_by_method(records: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Each method's first row (Table I's own, before variants of the same preset)."""
    return {r["method"]: r for r in reversed(records)}


def calibration_text(measured: dict[str, Any] | None, plotted: bool) -> str:
    lines = ["### Confidence: calibration on held-out scenes\n"]
    if not measured or "skipped" in measured:
        return "\n".join(lines
                         + [f"Not measured: {(measured or {}).get('skipped', 'no calibration in these results')}."])
    accepted = measured["acceptance"]
    share = accepted["share_of_reachable"]
    lines += [
        f"Every hypothesis of the four methods on {', '.join(measured['sequences'])} ({measured['hypotheses']} in all) "
        "scored by a confidence model fitted on the other scenes only (leave one scene out; "
        "`clipclique/benchmark/calibration.py`). The shipped model (`clipclique/data/confidence.json`, "
        "`tools/fit_confidence.py`) is fitted on all of them; these figures measure how that recipe transfers to a "
        "scene it has not seen.\n",
        f"- Expected calibration error (10 bins): **{measured['ece']:.3f}** over hypotheses, "
        f"{measured['ece_answers']:.3f} over each frame's answer (its most confident pose); goal < 0.05: "
        f"**{'met' if measured['ece'] < 0.05 else 'not met'}**.",
        f"- At 95% precision (a frame answers with its most confident pose, accepted from confidence "
        f"{fmt(accepted['threshold'], lambda v: f'{v:.2f}')}): {accepted['accepted_correct']} of the "
        f"{accepted['frames_with_correct']} frames that have a correct hypothesis are accepted correctly, "
        f"**{fmt(share, percent_of)}**; goal 80%: **{'met' if share >= 0.8 else 'not met'}**.",
        "- With `--min-confidence 0.95` (and `inliers.rerank = confidence`): "
        f"{accepted['at_min_confidence']['accepted']} frames answered, "
        f"{fmt(accepted['at_min_confidence']['precision'], percent_of)} of them right, "
        f"{fmt(accepted['at_min_confidence']['share_of_reachable'], percent_of)} of the frames with "
        "a correct hypothesis.\n",
        "| Held-out scene | ECE | Frames with a correct hypothesis | Accepted at 95% precision | Threshold |",
        "|---|---|---|---|---|"]
    for scene, data in measured["by_scene"].items():
        a = data["acceptance"]
        lines.append(f"| {scene} | {data['ece']:.3f} | {a['frames_with_correct']} | {a['accepted_correct']} "
                     f"({fmt(a['share_of_reachable'], percent_of)}) | {fmt(a['threshold'], lambda v: f'{v:.2f}')} |")
    lines += ["", "| Method (answers pooled over the held-out scenes) | Frames with a correct hypothesis | "
              "Accepted at 95% precision | Threshold |", "|---|---|---|---|"]
    for method, a in measured["by_method"].items():
        lines.append(f"| {method} | {a['frames_with_correct']} | {a['accepted_correct']} "
                     f"({fmt(a['share_of_reachable'], percent_of)}) | {fmt(a['threshold'], lambda v: f'{v:.2f}')} |")
    if plotted:
        lines += ["", "![Reliability diagram on held-out scenes](reliability.png)"]
    return "\n".join(lines)


def percent_of(value: float) -> str:
    return f"{100 * value:.1f}%"


def claims_section(results: dict[str, Any]) -> str:
    lines = ["## The paper's claims against our numbers\n",
             "Top-1 success decides each comparison (ties are reported as ties); the gap is given in frames so it can "
             "be weighed: one or two frames in 120 is a small difference. On the demo the detector and CLIP are "
             "simulated, so an agreement or a disagreement here says how our implementation behaves on that data, "
             "not whether the paper's results hold on ScanNet or TUM.\n",
             "| Claim | Sequence | Ours | Verdict |", "|---|---|---|---|"]
    for name in results["sequences"]:
        for claim, ours, verdict in sequence_claims(results, name):
            lines.append(f"| {claim} | {name} | {ours} | {verdict} |")
    for claim, ours, verdict in global_claims(results):
        lines.append(f"| {claim} | {results['scalability']['scene']['sequence']} copies | {ours} | {verdict} |")
    return "\n".join(lines) + "\n"


def sequence_claims(results: dict[str, Any], name: str) -> list[tuple[str, str, str]]:
    checks = [
        ("CLIP-Clique beats every baseline", "methods", "CLIP-Clique"),
        ("Maximal cliques beat RANSAC and PROSAC", "inliers", "Maximal cliques"),
        ("Pose weights help (w_sim * w_com best)", "weights", "w_sim * w_com"),
        ("Adaptive matching is best", "matching", "Adaptive"),
        ("SH + CLIP beats either descriptor alone", "descriptors", "SH + CLIP"),
    ]
    out = []
    for claim, group, winner in checks:
        top1 = {r["label"]: r["summary"]["success@1"] for r in rows_of(results, name, group)
                if "summary" in r and r["label"] not in NOT_BASELINES}
        if winner not in top1 or len(top1) < 2:
            out.append((claim, "not testable here (a configuration did not run)", "–"))
            continue
        rivals = {label: v for label, v in top1.items() if label != winner}
        best_rival = max(rivals, key=rivals.get)
        ours = f"{winner} {100 * top1[winner]:.1f}% vs {best_rival} {100 * rivals[best_rival]:.1f}% (Top-1)"
        frames = results["sequences"][name]["frames"]
        gap = round(frames * abs(top1[winner] - rivals[best_rival]))
        ours += f", {gap} of {frames} frames apart" if gap else ""
        out.append((claim, ours, verdict(top1[winner], rivals[best_rival])))
    methods = {r["label"]: r["summary"]["success@1"] for r in rows_of(results, name, "methods") if "summary" in r}
    if {"CLIP-Clique", LITERAL} <= methods.keys():
        ours, literal = methods["CLIP-Clique"], methods[LITERAL]
        out.append(("Beyond the paper: CLIP-Clique beats the literal reference by at least 5 points of Top-1",
                    f"{100 * ours:.1f}% vs {100 * literal:.1f}%", verdict(ours, literal + 0.05)))
    te = {r["label"]: r["summary"]["te_median_m"] for r in rows_of(results, name, "weights") if "summary" in r}
    if {"none", "w_sim * w_com"} <= te.keys():  # weights move the pose more than they move success
        both, none = te["w_sim * w_com"], te["none"]
        out.append(("Pose weights lower the error (median TE, w_sim * w_com vs none)", f"{both:.3f} m vs {none:.3f} m",
                    verdict(-both, -none, resolution=5e-4)))
    sims = {r["overrides"]["similarity.descriptor"]: r["summary"]
            for r in rows_of(results, name, "descriptors") if "summary" in r}
    if {"clip", "sh"} <= sims.keys():
        clip, sh = sims["clip"], sims["sh"]
        agrees = all(abs(sims[d]["similarity_true_p90"] - PAPER_SIMILARITY[d]) < 0.15 for d in PAPER_SIMILARITY)
        out.append(("True pairs: CLIP similarity reaches about 0.4 where SH reaches about 0.8",
                    f"90th percentile CLIP {clip['similarity_true_p90']:.2f}, SH {sh['similarity_true_p90']:.2f} "
                    f"(means {clip['similarity_true_mean']:.2f}, {sh['similarity_true_mean']:.2f})",
                    "agrees" if agrees else "**disagrees**"))
    return out


def global_claims(results: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The scalability claim against the scene-copies curve (the paper's set-up)."""
    scene = results["scalability"]["scene"]
    near = scene["landmarks_at_1s"] is not None and 0.5 <= scene["landmarks_at_1s"] / PAPER_LANDMARKS_AT_1S <= 2
    quadratic = 1.6 <= scene["exponent_total"] <= 2.4
    faster = scene["ms_at_paper_size"] < 500
    ours = f"{one_second(scene)}; exponent {scene['exponent_total']:.2f}"
    if near and quadratic:
        return [(CLAIM_SCALE, ours, "agrees")]
    return [(CLAIM_SCALE, ours, "**disagrees**"
             + (" (ours is faster and grows more slowly)" if faster and not quadratic else ""))]


def verdict(ours: float, rival: float, resolution: float = 0.0) -> str:
    """Whether ours is higher; values closer than the `resolution` they are printed with tie."""
    if math.isnan(ours) or math.isnan(rival):
        return "–"
    if math.isclose(ours, rival) or abs(ours - rival) < resolution:
        return "ties"
    return "agrees" if ours > rival else "**disagrees**"


def fmt(value: float | None, style: Callable[[float], str]) -> str:
    return "–" if value is None or (isinstance(value, float) and math.isnan(value)) else style(value)


# --------------------------------------------------------------------------------------------- plots


def plot_methods(results: dict[str, Any], path: Path) -> bool:
    """Grouped bars: Top-1/3/5 success of each method, one panel per sequence."""
    names = list(results["sequences"])
    figure, axes = plt.subplots(1, len(names), figsize=(5 * len(names), 3.6), squeeze=False, sharey=True)
    for axis, name in zip(axes[0], names):
        rows = [r for r in rows_of(results, name, "methods") if "summary" in r]
        x = np.arange(len(rows))
        for offset, k in zip((-0.27, 0.0, 0.27), (1, 3, 5)):
            axis.bar(x + offset, [100 * np.nan_to_num(r["summary"][f"success@{k}"]) for r in rows], 0.26,
                     label=f"Top-{k}")
        axis.set_xticks(x, [r["label"] for r in rows])
        axis.set_title(f"{name} ({simulated_tag(results['sequences'][name])})", fontsize=9)
        axis.set_ylim(0, 100)
        axis.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("success rate [%]")
    axes[0][0].legend(fontsize=8)
    return save(figure, path)


def plot_alpha(results: dict[str, Any], path: Path) -> bool:
    figure, axis = plt.subplots(figsize=(5.5, 3.6))
    plotted = False
    for name, description in results["sequences"].items():
        rows = [r for r in rows_of(results, name, "alpha") if "summary" in r]
        if rows:
            axis.plot([float(r["label"]) for r in rows], [100 * np.nan_to_num(r["summary"]["success@1"]) for r in rows],
                      marker="o", label=f"{name} ({simulated_tag(description)})")
            plotted = True
    if not plotted:
        plt.close(figure)
        return False
    axis.axvline(0.7, color="grey", linestyle=":", label="paper default 0.7")
    axis.set(xlabel="alpha (0 = SH only, 1 = CLIP only)", ylabel="Top-1 success [%]", ylim=(0, 100), xlim=(-0.02, 1.02))
    axis.grid(alpha=0.3)
    axis.legend(fontsize=8)
    return save(figure, path)


def plot_scalability(results: dict[str, Any], path: Path) -> bool:
    """Whole-query latency of both set-ups on log axes, with the paper's quadratic for reference."""
    figure, axis = plt.subplots(figsize=(6, 4))
    for key, label in (("scene", f"{results['scalability']['scene']['sequence']} copies"),
                       ("synthetic", "synthetic rooms (simulated)")):
        data = results["scalability"][key]
        n = [r["landmarks"] for r in data["rows"]]
        axis.loglog(n, [r["median_total_ms"] for r in data["rows"]], marker="o",
                    label=f"{label}, whole query (slope {data['exponent_total']:.2f})")
        axis.loglog(n, [r["median_ms"] for r in data["rows"]], marker=".", linestyle=":",
                    label=f"{label}, matching + inliers + pose (slope {data['exponent_algorithm']:.2f})")
    n = np.geomspace(50, 5000, 20)
    axis.loglog(n, 1000.0 * (n / PAPER_LANDMARKS_AT_1S) ** 2, "k--", alpha=0.5,
                label=f"quadratic through the paper's ~{PAPER_LANDMARKS_AT_1S} landmarks at 1 s")
    axis.plot([PAPER_LANDMARKS_AT_1S], [1000.0], "k*", markersize=10)
    axis.set(xlabel="landmarks in the map", ylabel="median latency per query [ms]")
    axis.set_title("CLIP-Clique scalability: copies side by side", fontsize=9)
    axis.grid(which="both", alpha=0.3)
    axis.legend(fontsize=6.5)
    return save(figure, path)


def plot_calibration(results: dict[str, Any], path: Path) -> bool:
    measured = results.get("calibration")
    if not measured or "skipped" in measured:
        return False
    calibration.plot_reliability(measured["reliability"], "Confidence on held-out scenes", path)
    return True


def simulated_tag(description: dict[str, Any]) -> str:
    parts = [role for role, part in (("detector", description["detector"]), ("CLIP", description["encoder"]))
             if part and part["simulated"]]
    return f"simulated {' + '.join(parts)}" if parts else "nothing simulated"


def save(figure: plt.Figure, path: Path) -> bool:
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
    return True


# ------------------------------------------------------------------------------------ README figures

README_REGION = re.compile(r"(<!-- figures:(\w+) -->\n)(.*?)(<!-- /figures -->)", re.DOTALL)


def readme_figures(results: dict[str, Any]) -> dict[str, str]:
    """The README's generated regions (`<!-- figures:NAME -->` ... `<!-- /figures -->`) from a suite run."""
    host = results["machine"]
    where = (f"Measured by `make docs` ({results['created'][:10]}, commit {host['commit']}) on {host['cores']} "
             f"CPU cores ({host['cpu']}); the suite took {results['wall_time_s']:.0f} s.")
    names = list(results["sequences"])
    lines = [where, "", "| method | " + " | ".join(names) + " | matching + inliers + pose per query |",
             "|---|" + "---|" * (len(names) + 1)]
    for label in ("X-View", "SH", "CLIP-Loc", "CLIP-Clique"):
        records = [next(r for r in rows_of(results, name, "methods") if r["label"] == label) for name in names]
        cells = [f"{100 * r['summary']['success@1']:.1f}%" if "summary" in r else "not run" for r in records]
        times = [r["summary"]["time_ms_median"] for r in records if "summary" in r]
        time = "-" if not times else f"{min(times):.1f}-{max(times):.1f} ms" if max(times) - min(times) >= 0.05 else \
            f"{times[0]:.1f} ms"
        title = f"**{label}**" if label == "CLIP-Clique" else label
        lines.append(f"| {title} | " + " | ".join(cells) + f" | {time} |")
    scene = results["scalability"]["scene"]
    rows = scene["rows"]
    shown = sorted({0, min(range(len(rows)), key=lambda i: abs(rows[i]["landmarks"] - 1000)), len(rows) - 1})
    lines += ["", f"Scalability (the {scene['sequence']} map copied as rooms side by side), matching + inliers + "
              "pose per query: "
              + ", ".join(f"{rows[i]['landmarks']:,} landmarks {rows[i]['median_ms']:.1f} ms (whole query "
                          f"{rows[i]['median_total_ms']:.1f} ms)" for i in shown)
              + f"; growth exponent {scene['exponent_total']:.2f} (the paper: ~{PAPER_LANDMARKS_AT_1S} landmarks "
              "within 1 s, quadratic)."]
    return {"benchmark": "\n".join(lines) + "\n"}


def update_readme(text: str, figures: dict[str, str]) -> str:
    """`text` with the generated region of each of `figures` replaced; a figure without exactly one region is an
    error. Regions of other generators (tools/scene_stats.py's) are left as they are."""
    found = [name for _, name, _, _ in README_REGION.findall(text)]
    if missing := [name for name in figures if found.count(name) != 1]:
        raise ValueError(f"README regions {found} do not match the figures {missing} (one region each)")
    return README_REGION.sub(lambda m: m.group(1) + figures.get(m.group(2), m.group(3)) + m.group(4), text)
