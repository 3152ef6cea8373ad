"""bench_seeds' headline tables: per seed, then as mean ± spread over the seeds, the numbers that say
whether a decomposition is good enough to repaint a textured picture with.

- the decomposition: the shading's texture leakage beside the ground-truth shading's (and the
  difference), the shading's PSNR on glossy and on matte surfaces, the residual's recall of the true
  residual and its false share on matte surfaces (:mod:`backend.eval.gloss`), the albedo's PSNR, the
  full image's PSNR against 3DGS's (ours minus 3DGS, dB) and the time ratio (decomposition ÷ 3DGS,
  same views);
- per edit, the multi-view bake: the image in the region with the edit's true shading and residual
  beside the image with the decomposition's own S and R (what a user renders; the "oracle" column
  puts the true edited albedo under our S and R, which isolates the lighting's error, e.g. a ghost of
  the old texture left in S), and the multi-view bake's lead over the single-view bake under each.

With a baseline (an earlier bench_seeds.json, e.g. the same seeds at the previous defaults),
:func:`baseline_table` puts its mean ± std of every headline column beside this run's, with the
difference of the means.

The values come from the per-seed entries (:func:`backend.bench.bench_seeds.decomposition_headline`,
``edit_headline``) and their aggregate (:func:`backend.bench.seed_stats.aggregate`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from backend.bench.seed_stats import cell, markdown

DECOMPOSITION_COLUMNS = (("leakage", "leakage"), ("leakage GT", "leakage_gt"), ("leakage − GT", "leakage_vs_gt"),
                         ("S glossy dB", "shading_psnr_glossy"), ("S matte dB", "shading_psnr_matte"),
                         ("S ÷ true S, glossy", "shading_ratio_glossy"),
                         ("R recall", "residual_recall"), ("R false on matte", "residual_false_matte"),
                         ("albedo dB", "albedo_psnr"), ("ours − 3DGS dB", "full_vs_3dgs_db"),
                         ("time ÷ 3DGS", "time_vs_3dgs"))
"""(header, decomposition metric) of the decomposition's headline table."""
EDIT_COLUMNS = (("image, true S and R", "image"), ("image, our S and R", "image_decomposed"),
                ("oracle, our S and R", "oracle_image_decomposed"), ("lead, true S and R", "lead_image_db"),
                ("lead, our S and R", "lead_image_decomposed_db"))
"""(header, edit metric) of the edits' headline table: the multi-view bake's region PSNR (dB) and its
lead over the single-view bake."""


def leakage_vs_gt(decomposition: Mapping[str, Any]) -> float | None:
    """The learned shading's leakage minus the ground-truth shading's (None when either is missing)."""
    ours, gt = decomposition.get("leakage"), decomposition.get("leakage_gt")
    return None if ours is None or gt is None else round(float(ours) - float(gt), 4)


def _mean_std(s: Mapping[str, Any] | None) -> str:
    if not s or s.get("mean") is None:
        return "-"
    return f"{cell(s['mean'])} ± {cell(s.get('std'))}"


def headline_table(seeds: Mapping[str, Mapping[str, Any]], agg: Mapping[str, Any]) -> str:
    """Markdown: the decomposition's headline per seed and a 'mean ± std' row; then per seed and edit
    the bake's image under the true and the decomposed S and R and its leads, with a 'mean ± std' row
    per edit (a failed edit shows its error)."""
    dec_rows = [[k, *(cell(e.get("decomposition", {}).get(m)) for _, m in DECOMPOSITION_COLUMNS)]
                for k, e in seeds.items()]
    dec_rows.append(["mean ± std", *(_mean_std(agg.get("decomposition", {}).get(m)) for _, m in DECOMPOSITION_COLUMNS)])
    dec = markdown(["seed", *(h for h, _ in DECOMPOSITION_COLUMNS)], dec_rows)
    rows = []
    for k, e in seeds.items():
        for name, r in e.get("edits", {}).items():
            rows.append([k, name, f"failed: {r['error']}"] if r.get("error") else
                        [k, name, *(cell((r.get("metrics") or {}).get(m)) for _, m in EDIT_COLUMNS)])
    for name, e in agg.get("edits", {}).items():
        rows.append(["mean ± std", name, *(_mean_std(e["metrics"].get(m)) for _, m in EDIT_COLUMNS)])
    edits = markdown(["seed", "edit", *(h for h, _ in EDIT_COLUMNS)], rows)
    return dec + "\n\n" + edits


def baseline_table(agg: Mapping[str, Any], base: Mapping[str, Any], base_label: str) -> str:
    """Markdown: every headline column (decomposition, then each edit's) as this run's mean ± std beside
    the baseline's (``base``: the aggregate of an earlier run, named ``base_label``) and the difference of
    the means (this run minus the baseline), over the seeds each aggregate covers."""
    def diff(a: Mapping[str, Any] | None, b: Mapping[str, Any] | None) -> str:
        if not a or not b or a.get("mean") is None or b.get("mean") is None:
            return "-"
        return f"{a['mean'] - b['mean']:+.2f}"

    rows = []
    for head, m in DECOMPOSITION_COLUMNS:
        a, b = agg.get("decomposition", {}).get(m), base.get("decomposition", {}).get(m)
        rows.append([head, _mean_std(a), _mean_std(b), diff(a, b)])
    for name in agg.get("edits", {}):
        for head, m in EDIT_COLUMNS:
            a = agg["edits"][name]["metrics"].get(m)
            b = ((base.get("edits", {}).get(name) or {}).get("metrics") or {}).get(m)
            rows.append([f"{name}: {head}", _mean_std(a), _mean_std(b), diff(a, b)])
    seeds = ", ".join(agg.get("seeds", []))
    base_seeds = ", ".join(base.get("seeds", []))
    return (f"this run (seeds {seeds}) against {base_label} (seeds {base_seeds})\n\n"
            + markdown(["metric", "this run", "baseline", "difference"], rows))
