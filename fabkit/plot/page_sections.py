"""A run's figures in words: :func:`run_page` and :func:`design_page` build the
:class:`~fabkit.plot.page.Page` of ``fabkit run`` and ``fabkit plot`` from their sections,
verdict first (:mod:`fabkit.plot.page_verdict`); the sections after it are here: the
shapes, the design, the part, the layers, the print lines, the machine file, its reading
back, the send and the files.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from fabkit.calibration import LABELS
from fabkit.design.check import RESIDUAL_TITLES, RESIDUALS
from fabkit.plot.page import (
    Block,
    Code,
    Facts,
    Figure,
    Link,
    Page,
    Paragraph,
    Section,
    Shape3D,
    Span,
    Table,
    Text,
    View3D,
    as_sentence,
    as_spans,
    in_words,
    number,
    percent,
)
from fabkit.plot.page_verdict import verdict_section


def run_page(
    figures: Mapping[str, Any],
    pictures: Sequence[tuple[str, Path]],
    preview: tuple[str, Path] | None,
    folder: Path,
    shapes: tuple[Shape3D, ...] = (),
) -> Page:
    """The page of a ``fabkit run``: ``figures`` as in ``report.json``, the design
    ``pictures`` and the machine file's ``preview`` ((caption, PNG) pairs), written in
    ``folder`` (the run's output folder); ``shapes``: the final verdict's, for the 3D
    view."""
    spec = Path(figures["spec"]).name
    sections = [
        verdict_section(figures),
        *([_shapes_section(figures, folder, shapes)] if figures.get("shapes") else []),
        _design_section(figures, pictures),
        _part_section(figures["part"]),
        *([_layers_section(figures)] if figures.get("layers") else []),
        _fabrication_section(figures, preview),
        _machine_file_section(figures),
        *([_verify_section(figures)] if figures.get("verify") else []),
        *([_sent_section(figures["sent"])] if figures.get("sent") else []),
        _files_section(figures, folder),
    ]
    return Page(
        f"{spec}: {figures['verdict']['headline']}",
        ("fabkit run ", Code(spec)),
        tuple(sections),
        folder,
        as_spans(figures["notice"]) if figures.get("notice") else (),
    )


def design_page(
    name: str,
    figures: Mapping[str, Any],
    pictures: Sequence[tuple[str, Path]],
    meshes: Sequence[str],
    folder: Path,
) -> Page:
    """The page of ``fabkit plot``: the design file ``name``, its ``figures`` (``valid
    points``, ``grid step``, ``check``), its ``pictures`` and patch ``meshes``."""
    solved = (f"{figures['valid points']} grid points solved, grid step {figures['grid step']:g}.",)
    blocks = (Paragraph(solved), *_check_blocks(figures["check"]), *_figures(pictures))
    files = Paragraph(("The patch on every target as a mesh: ", *_file_list(meshes), "."))
    return Page(
        f"{name}: check {'passed' if figures['check']['passed'] else 'FAILED'}",
        ("fabkit plot ", Code(name)),
        (Section("The design", blocks), Section("Files", (files,))),
        folder,
    )


def _shapes_section(
    figures: Mapping[str, Any], folder: Path, shapes_3d: tuple[Shape3D, ...]
) -> Section:
    """A picture per target of the sheet beside it, the 3D view, and the meshes."""
    shapes = figures["shapes"]
    lines = {t["target"]: t for t in figures["verdicts"][-1]["targets"]}
    blocks: list[Block] = []
    for shape in shapes["targets"]:
        target = lines[shape["target"]]
        mirror = (
            " The sheet takes the target's mirror image; it is shown as it is, so its distances"
            " here are those to the target itself, no smaller than the verdict's (measured"
            " after mirroring)."
            if target["mirror_image"]
            else ""
        )
        caption = (
            f"{shape['target']}: the target (left, grey) and the sheet {shapes['what']} under "
            f"its stimulus (right), from the same view at the same scale (mm); the sheet is "
            "coloured by the distance from each of its points to the same material point of "
            "the target (mm), after the best rotation and translation; the colour bar marks "
            f"its RMS distance and the limit.{mirror}"
        )
        if "picture" in shape:  # none with --no-pictures
            blocks.append(Figure(folder / shape["picture"], caption))
    if shapes_3d:
        blocks.append(
            View3D(
                shapes_3d,
                f"Every target (grey) and the sheet {shapes['what']} under its stimulus, "
                "coloured by its distance to the target (mm, each target on its own scale), "
                "in mm: drag to turn, scroll to zoom, a button per target.",
            )
        )
    meshes = [shape["mesh"] for shape in shapes["targets"]]
    blocks.append(
        Paragraph(
            (
                f"The sheet {shapes['what']} under each target's stimulus, as meshes (PLY, mm, "
                "placed on the target, with each vertex's distance to it in mm): ",
                *_file_list(meshes),
                ".",
            )
        )
    )
    return Section("The shapes it will make", tuple(blocks))


def _file_list(paths: Sequence[str]) -> list[Span]:
    """Links to files, separated by commas."""
    spans: list[Span] = []
    for k, path in enumerate(paths):
        spans += [Link(path, path), *([", "] if k < len(paths) - 1 else [])]
    return spans


def _design_section(figures: Mapping[str, Any], pictures: Sequence[tuple[str, Path]]) -> Section:
    """The solve and the independent check, with the design's pictures."""
    solve = figures["solve"]
    areas = solve["area_design_units2"]
    blocks: list[Block] = [
        Paragraph(
            (
                f"{solve['valid_points']} grid points solved in {solve['solve_seconds']:.2f} s. "
                "Area of the solved patch on every surface (design units²; the flat sheet is "
                "the first):",
            )
        ),
        Table(("surface", "area (design units²)"), tuple((n, number(a)) for n, a in areas.items())),
    ]
    stops = solve["stop_counts"]
    if stops:
        blocks.append(Paragraph(("Where the solver stopped marching, and why:",)))
        blocks.append(
            Table(
                ("reason", "grid points"),
                tuple((as_spans(reason), str(count)) for reason, count in stops.items()),
            )
        )
    drawn = _figures(pictures) or [Paragraph(("No pictures drawn (fabkit run --no-pictures).",))]
    blocks += [*_check_blocks(figures["check"]), *drawn]
    return Section("The design", tuple(blocks))


def _check_blocks(check: Mapping[str, Any]) -> list[Block]:
    """The check's verdict, limits and residuals per surface."""
    limits = check["tolerances"]
    result = "passed" if check["passed"] else "FAILED"
    sentence = (
        f"The independent check {result}: on every surface the isometry residuals (lengths "
        f"along u and v, angle) must have a median of at most {limits['isometry_median']:g} and "
        f"a 95th percentile of at most {limits['isometry_p95']:g}, the curvature residual a "
        f"median of at most {limits['curvature_median']:g} (relative; median / 95th percentile "
        "over the checked points):"
    )
    header = (
        "surface",
        "points checked",
        *(RESIDUAL_TITLES[key] for key in RESIDUALS),
        "within the limits",
    )
    rows = tuple(
        (
            surface["name"],
            str(surface["checked_points"]),
            *(f"{surface[key]['median']:.2g} / {surface[key]['p95']:.2g}" for key in RESIDUALS),
            "yes" if surface["passed"] else "NO",
        )
        for surface in check["surfaces"]
    )
    return [Paragraph((sentence,)), Table(header, rows)]


def _figures(pictures: Sequence[tuple[str, Path]]) -> list[Block]:
    return [Figure(path, caption) for caption, path in pictures]


def _part_section(part: Mapping[str, Any]) -> Section:
    """The part of the flat sheet that is made, and what each step removed."""
    unit = "mm" if part["units"].startswith("mm") else "design units"
    area = "mm²" if unit == "mm" else "design units²"
    rows: list[tuple[str, Text]] = [
        ("solved area", (f"{number(part['solved_area'])} {area}",)),
        ("kept of the solved area", (f"{part['kept_pct']:g} % ({number(part['area'])} {area})",)),
    ]
    for step, share in part["removed_pct"].items():
        rows.append((_removed_label(step, part, unit), (f"{share:g} % of the solved area",)))
    if "thickness" in part:
        rows.append(("sheet thickness", (f"{part['thickness']:.3g} {unit}",)))
        rows.append(
            ("bending length, √(thickness × radius of curvature)",
             (f"{part['bending_length']:.3g} {unit}",))
        )  # fmt: skip
    if "outline" in part:
        rows.append(("outline given", as_spans(part["outline"])))
    return Section("The part that is made", (Facts(tuple(rows)),))


def _removed_label(step: str, part: Mapping[str, Any], unit: str) -> str:
    """What a step of the part's cut removed, in words."""
    if step.startswith("trim") and "trim_width" in part:
        width = f"{part['trim_width']:.3g} {unit}"
        under = f"under {part['trim_bending_lengths']:g} bending lengths ({width})"
        return f"trimmed: {under}" if step == "trim" else f"not trimmed (nearly all is {under})"
    words = {
        "margin": "removed: the margin along the solved region's border",
        "outline": "removed: outside the outline given",
        "min width": f"removed: narrower than {part['min_width']:.3g} {unit}",
    }
    return words.get(step, f"removed: {step}")


def _changes(refinement: Mapping[str, Any]) -> str:
    """``sphere 0.65 -> 0.33 %, bump 5.17 -> 0.28 %``: a refinement's RMS per target."""
    return ", ".join(
        f"{name} {before:.2f} -> {after:.2f} %"
        for name, before, after in zip(
            refinement["targets"],
            refinement["rms_pct_before"],
            refinement["rms_pct_after"],
            strict=True,
        )
    )


def _layers_words(layers: Mapping[str, Any]) -> str:
    """How the layers were chosen, in a sentence ending with a colon (the table follows)."""
    refinement = layers.get("refinement")
    if layers.get("refined") and refinement:
        printed = layers.get("printed_refinement")
        then = (
            f" Then refined as printed, the print's error read back and in the loop "
            f"({printed['simulations']} simulations; the worst of every print's error so "
            f"far, as printed and turned over: {_changes(printed)})."
            if printed
            else ""
        )
        prints = layers.get("prints") or []
        if prints:
            judged = "; ".join(f"{k + 1}: {p['headline']}" for k, p in enumerate(prints))
            then += f" Printed in memory and judged as fabricated, print {judged}."
        return (
            "The layers differ so that the sheet's natural curvature selects every target: "
            "the first-order layering refined against the simulation "
            f"({refinement['simulations']} simulations; RMS from the dome start: "
            f"{_changes(refinement)}; docs/layers.md).{then} What the refined layers program:"
        )
    share = f"{100 * layers.get('share', 1.0):.0f} % of the first-order layering"
    tried = layers.get("shares_tried") or {}
    if "refined" in tried:
        return (
            "The layers differ so that the sheet's natural curvature is a share of every "
            f"target's curvature: {share}, not refined (the refined layers formed fewer "
            "targets as designed; docs/layers.md):"
        )
    if tried:
        shares = ", ".join(f"{100 * float(label):g} %" for label in tried)
        return (
            "The layers differ so that the sheet's natural curvature is a share of every "
            f"target's curvature: {share} (shares tried, largest first: {shares}; the "
            "largest whose sheet as designed forms every target is kept; docs/layers.md):"
        )
    return (
        "The layers differ so that the sheet's natural curvature is a share of every "
        f"target's curvature: {share}, not judged: nothing was simulated (docs/layers.md):"
    )


def _layers_section(figures: Mapping[str, Any]) -> Section:
    """How much of each target's curvature the layers program."""
    layers = figures["layers"]
    rows = tuple(
        (
            name,
            "yes" if weight > 0 else "no",
            f"{100 * max(0.0, layers['curvature_matched'][name]):.0f} %",
            f"{100 * layers['right_side'][name]:.0f} %",
        )
        for name, weight in layers["weights"].items()
    )
    features = list(figures.get("channels", {}).values())
    if len(features) != len(layers["features_limited"]):
        features = [f"feature {k + 1}" for k in range(len(layers["features_limited"]))]
    limited = ", ".join(
        f"{name} at {100 * share:.0f} %"
        for name, share in zip(features, layers["features_limited"], strict=True)
    )
    reasons = tuple(
        Paragraph((f"{name}: {why}.",)) for name, why in layers.get("why", {}).items() if why
    )
    tried = layers.get("layers_tried") or {}
    printed = layers.get("counts_printed") or {}
    counts = (
        (
            Paragraph(
                (
                    f"{figures['verdicts'][0]['layers']} layers, chosen by the run (no "
                    "--layers) among the layer counts it judged as designed"
                    + (", when the print of its first choice missed (below):" if printed else ":"),
                )
            ),
            Table(("layers", "the sheet as designed"), tuple(tried.items())),
        )
        if tried and figures.get("verdicts")
        else ()
    )
    prints = (
        (
            Paragraph(
                (
                    "The print of the count chosen first missed a target: the run printed "
                    "the next count whose sheet as designed forms every target, in turn, and "
                    "kept the print that formed the most:",
                )
            ),
            Table(("layers", "the sheet as fabricated"), tuple(printed.items())),
        )
        if printed
        else ()
    )
    blocks = (
        *counts,
        *prints,
        Paragraph((_layers_words(layers),)),
        Table(
            (
                "target",
                "curvature asked for",
                "of its curvature programmed",
                "of its points bent to its own side",
            ),
            rows,
        ),
        *(
            (Paragraph(("Why a target gets little of its curvature:",)), *reasons)
            if reasons
            else ()
        ),
        Paragraph(
            (
                f"The process's range of each feature capped its difference between the layers "
                f"at a share of the points: {limited}. The layers' mean metric differs "
                f"from the design's by at most {100 * layers['metric_error_p99']:.2g} % at 99 % "
                f"of the grid points, and by {100 * layers['metric_error']:.2g} % at the worst "
                "one (relative).",
            )
        ),
    )
    return Section("Layers", blocks)


def _fabrication_section(figures: Mapping[str, Any], preview: tuple[str, Path] | None) -> Section:
    """What the machine makes: print lines, channels or an exposure pattern (``preview``
    None: no picture of it, ``--no-pictures``)."""
    picture = (Figure(preview[1], preview[0]),) if preview is not None else ()
    if "toolpath quality" in figures:
        return Section("Print lines", (*_print_lines(figures), *picture))
    if "mould" in figures:
        return Section("Baromorph channels", (*_channels(figures), *picture))
    return Section("Photoalignment pattern", picture)


def _print_lines(figures: Mapping[str, Any]) -> list[Block]:
    """The channels that carry the features, and the quality of every layer's lines."""
    channels = "; ".join(
        f"{features} as the {LABELS.get(parameter, parameter)}"
        for parameter, features in figures["channels"].items()
    )
    header = (
        "layer",
        "not covered, as planned",
        "overlap, as planned",
        "mean angle to the director, as planned (deg)",
        "print lines",
        "printing (mm)",
        "travel between lines (mm)",
    )
    rows = tuple(
        (
            str(k + 1),
            percent(q["empty_fraction"]),
            percent(q["mean_overlap"]),
            f"{q['mean_angle_error_deg']:.2f}",
            str(q["paths"]),
            number(q["print_length_mm"]),
            number(q["travel_between_lines_mm"]),
        )
        for k, q in enumerate(figures["toolpath quality"])
    )
    sentence = f"Print lines along the director; the features go to the machine as {channels}."
    return [Paragraph((sentence,)), Table(header, rows)]


def _channels(figures: Mapping[str, Any]) -> list[Block]:
    """The baromorph channels' checks."""
    c = figures["channels"]
    rows: tuple[tuple[str, Text], ...] = (
        ("channels", (str(c["channels"]),)),
        ("valid polygons", ("yes" if c["valid"] else "NO",)),
        ("one connected network", ("yes" if c["connected"] else "NO",)),
        ("thinnest wall", (f"{c['min_wall_mm']:.3g} mm",)),
        ("channel width error, largest", (percent(c["max_width_error"]),)),
        ("channel width error, mean", (percent(c["mean_width_error"]),)),
        ("cuts across the channels measured", (str(c["width_samples"]),)),
        ("casting mould (STL)", as_spans(figures["mould"])),
    )  # fmt: skip
    return [Facts(rows)]


def _machine_file_section(figures: Mapping[str, Any]) -> Section:
    """Every machine file written, its figures in words."""
    blocks = tuple(
        Paragraph(as_spans(as_sentence(summary.replace(" mm^3", " mm³"))))
        for summary in figures["exports"].values()
    )
    return Section("The machine file", blocks)


def _verify_section(figures: Mapping[str, Any]) -> Section:
    """The machine file read back: coverage, director and features per layer, notes."""
    verify = figures["verify"]
    own = verify["process"] == f"machine {verify['machine']}"
    process: Text = ("its own process",) if own else ("the process ", *as_spans(verify["process"]))
    opening: Text = (
        Code(figures["machine file"]["file"]),
        " read back as ",
        Code(verify["machine"]),
        " reads it, with ",
        *process,
        "; placed by the ",
        *as_spans(verify["placement"]),
        f"; on cells of {verify['cell_mm']:.3g} mm. Over the cells inside the part, every layer "
        "against its design (feature errors as a share of the feature's designed range):",
    )
    layers = verify["layers"] or [{"layer": 1, **verify}]
    features = [f"{f['feature']}, as the {_label(f['channel'])}," for f in layers[0]["features"]]
    header = (
        "layer",
        "not covered, read back",
        "overlap, read back",
        "director error, read back: mean / 95th percentile (deg)",
        *(f"{name} error: RMS / 95th percentile" for name in features),
    )
    rows = tuple(
        (
            str(layer["layer"]),
            percent(layer["empty_fraction"]),
            percent(layer["mean_overlap"]),
            f"{layer['director_mean_deg']:.2f} / {layer['director_p95_deg']:.2f}",
            *(f"{f['rms_pct']:.2f} % / {f['p95_pct']:.2f} %" for f in layer["features"]),
        )
        for layer in layers
    )
    blocks: list[Block] = [Paragraph(opening), Table(header, rows)]
    if verify["targets"]:
        times = ", ".join(f"{t['target']} {t['seconds']:.1f} s" for t in verify["targets"])
        blocks.append(
            Paragraph(
                (
                    "The simulations of the sheet as fabricated used "
                    f"{verify['targets'][0]['triangles']} triangles each and took {times}.",
                )
            )
        )
    notes = [*verify["notes"], f"reading back took {verify['seconds']:.1f} s in all"]
    spans = [span for note in notes for span in (*as_spans(as_sentence(in_words(note))), " ")]
    blocks.append(Paragraph(tuple(spans[:-1])))
    return Section("The machine file read back", tuple(blocks))


def _label(parameter: str) -> str:
    """A channel's parameters (``a, b``) in words."""
    return ", ".join(LABELS.get(p.strip(), p.strip()) for p in parameter.split(","))


def _sent_section(sent: Mapping[str, Any]) -> Section:
    """The send's figures."""
    if "host" in sent:
        rows: tuple[tuple[str, Text], ...] = (
            ("printer host", (Code(sent["host"]), f" ({sent['server']})")),
            ("file on the host", (Code(sent["file"]),)),
            ("uploaded", (f"{sent['uploaded_bytes']} bytes",)),
            ("started", ("yes" if sent["started"] else "no",)),
            ("state at the end", (sent["state"],)),
            ("done", (_percent_or_unknown(sent["completion_percent"]),)),
            ("time", (f"{sent['seconds']:.1f} s",)),
        )  # fmt: skip
        return Section("Sent to the printer host", (Facts(rows),))
    rows = (
        ("port", (Code(sent["port"]),)),
        ("protocol", (sent["protocol"],)),
        ("lines sent", (f"{sent['job_lines']} (file lines {sent['file_lines']})",)),
        ("time", (f"{sent['seconds']:.3g} s ({sent['lines_per_second']:.0f} lines per second)",)),
        ("lines sent again", (str(sent["resent_lines"]),)),
        ("status queries between lines", (str(sent["status_queries_between_lines"]),)),
        ("recoveries from lost answers", (str(sent["recoveries_from_lost_answers"]),)),
    )
    return Section("Sent to the printer", (Facts(rows),))


def _percent_or_unknown(value: float | None) -> str:
    return "unknown" if value is None else f"{value:.0f} %"


def _files_section(figures: Mapping[str, Any], folder: Path) -> Section:
    """The meshes of the patches."""
    meshes = [_relative(path, folder) for path in figures["meshes"]]
    return Section(
        "Files",
        (
            Paragraph(
                (
                    "The patch on every surface as a mesh (design units): ",
                    *_file_list(meshes),
                    ". The raw figures of this page: ",
                    Link("report.json", "report.json"),
                    " (docs/report.md).",
                )
            ),
        ),
    )


def _relative(path: str, folder: Path) -> str:
    """``path`` relative to ``folder`` when inside it (as the page links it)."""
    try:
        return Path(path).resolve().relative_to(folder.resolve()).as_posix()
    except ValueError:
        return path
