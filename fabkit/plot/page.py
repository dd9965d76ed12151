"""A run's figures in words: the report page as plain data, verdict first.

:func:`run_page` turns ``fabkit run``'s key figures (``report.json``'s data) into a
:class:`Page`: sections of sentences, label-value lists and flat tables, every label in
words and every figure with its unit; :mod:`fabkit.plot.html` writes it as HTML. The
order is what a reader asks: does the sheet form the targets (the verdict, the machine
file, warnings), what shapes it takes (a picture per target), then the design, the part,
the layers, the print lines, the machine file, its reading back and the send. Names a
user or a file chose (files, the machine profile, spec keys) are :class:`Code`; the raw
figures stay in ``report.json`` (docs/report.md).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fabkit.calibration import LABELS
from fabkit.design.check import RESIDUAL_TITLES, RESIDUALS


@dataclass(frozen=True)
class Code:
    """A name as written in a file or on the command line (a file, a machine, a key)."""

    text: str


@dataclass(frozen=True)
class Link:
    """A link to a file the run wrote (``href`` relative to the page)."""

    text: str
    href: str


Span = str | Code | Link
Text = tuple[Span, ...]


@dataclass(frozen=True)
class Paragraph:
    """Sentences; ``style``: "" (plain), "headline", "formed", "missed" or "notice"."""

    text: Text
    style: str = ""


@dataclass(frozen=True)
class Facts:
    """Label-value rows (the value with its unit)."""

    rows: tuple[tuple[str, Text], ...]


@dataclass(frozen=True)
class Table:
    """A flat table: ``header`` labels and ``rows`` of cells."""

    header: tuple[str, ...]
    rows: tuple[tuple[Text, ...], ...]


@dataclass(frozen=True)
class Figure:
    """A picture (PNG) the run wrote, with its ``caption`` (also its alternative text)."""

    path: Path
    caption: str


Block = Paragraph | Facts | Table | Figure


@dataclass(frozen=True)
class Section:
    heading: str
    blocks: tuple[Block, ...]


@dataclass(frozen=True)
class Page:
    """The page: its ``title`` (the browser's), ``heading`` and ``sections``; ``folder`` is
    where it is written (links and pictures are relative to it); ``notice``, if any, is its
    first line (features left out of the machine file on purpose)."""

    title: str
    heading: Text
    sections: tuple[Section, ...]
    folder: Path
    notice: Text = ()


def run_page(
    figures: Mapping[str, Any],
    pictures: Sequence[tuple[str, Path]],
    preview: tuple[str, Path],
    folder: Path,
) -> Page:
    """The page of a ``fabkit run``: ``figures`` as in ``report.json``, the design
    ``pictures`` and the machine file's ``preview`` ((caption, PNG) pairs), written in
    ``folder`` (the run's output folder)."""
    spec = Path(figures["spec"]).name
    sections = [
        _verdict_section(figures),
        _shapes_section(figures, folder),
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
        _spans(figures["notice"]) if figures.get("notice") else (),
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


def _verdict_section(figures: Mapping[str, Any]) -> Section:
    """Which targets the sheet forms, the machine file, warnings and ignored features."""
    verdict = figures["verdict"]
    final = figures["verdicts"][-1]
    blocks: list[Block] = [Paragraph((_sentence(verdict["headline"]),), "headline")]
    blocks.append(Paragraph((_sheet_simulated(final, figures),)))
    for target in final["targets"]:
        blocks.append(Paragraph((target["line"],), "formed" if target["formed"] else "missed"))
    if final["what"] == "as fabricated":
        designed = figures["as designed"]
        blocks.append(Paragraph((_compared("As designed", designed),)))
    if figures.get("layers"):
        alone = figures["layers"]["metric alone"]
        blocks.append(Paragraph((_compared("Programmed by its metric alone", alone),)))
    blocks.extend(_machine_file_sentences(figures))
    blocks.append(Paragraph(_warnings(figures)))
    return Section("Verdict", tuple(blocks))


def _sentence(text: str) -> str:
    """``text`` with a capital first letter and a full stop."""
    return text[:1].upper() + text[1:] + ("" if text.endswith(".") else ".")


def _sheet_simulated(verdict: Mapping[str, Any], figures: Mapping[str, Any]) -> str:
    """What sheet the verdict is about and how it was simulated."""
    layers = verdict["layers"]
    thickness = verdict.get("thickness_mm")
    sheet = f"{layers} layer{'s' if layers > 1 else ''}" + (
        f", {thickness:.3g} mm thick" if thickness is not None else ""
    )
    if verdict["what"] == "as fabricated":
        source = "the machine file read back as the machine reads it"
    elif figures.get("verify") is None:
        source = "the design (the machine file was not read back: --no-verify)"
    else:
        source = "the design (the machine file was read back but not simulated: see its notes)"
    return (
        f"The sheet {verdict['what']} ({sheet}, {figures['size_mm']:g} mm across) was "
        f"simulated from flat to every target's stimulus, from {source}. A target is formed "
        "when the simulation converged, the sheet is not the target's mirror image and it "
        "ends within the limit of the target (RMS distance after the best rigid motion, as a "
        "share of the patch diameter):"
    )


def _compared(what: str, verdict: Mapping[str, Any]) -> str:
    """Another verdict on the same targets in one sentence."""
    shapes = ", ".join(
        f"{t['target']} {t['rms_pct']:.2f} % RMS{_missed(t)}" for t in verdict["targets"]
    )
    formed = "forms every target" if verdict["formed"] else "does NOT form every target"
    return f"{what}, the sheet {formed}: {shapes}."


def _missed(target: Mapping[str, Any]) -> str:
    """`` (not formed: ...why)`` for a target not formed, else ""."""
    if target["formed"]:
        return ""
    reasons = [
        reason
        for reason, holds in (
            ("its mirror image", target["mirror_image"]),
            ("not converged", not target["converged"]),
            ("beyond the limit", target["rms_pct"] > target["limit_pct"]),
        )
        if holds
    ]
    return f" (not formed: {', '.join(reasons)})"


def _machine_file_sentences(figures: Mapping[str, Any]) -> list[Paragraph]:
    """The machine file in a sentence (its time and material where known), and the send."""
    machine_file = figures["machine file"]
    name = Code(machine_file["file"])
    head: list[Span] = ["The machine file ", name, " (", FORMATS[machine_file["format"]]]
    head += [" for ", Code(figures["machine"]), ")"]
    if "estimated_seconds" in machine_file:
        volume = machine_file["volume_mm3"]
        time = _duration(machine_file["estimated_seconds"])
        head.append(
            f" prints {machine_file['print_length_mm'] / 1000:.3g} m of road in "
            f"{machine_file['lines']} lines, in about {time} (the writer's estimate), with "
            f"{volume:.4g} mm³ of material ({volume / 1000:.3g} mL)."
        )
    elif "entities" in machine_file:
        entities = machine_file["entities"]
        layers = ", ".join(f"{count} on {layer}" for layer, count in entities.items() if count)
        head.append(f" draws {sum(entities.values())} entities ({layers}); a drawing has no "
                    "time or material estimate.")  # fmt: skip
    else:
        head.append(
            f" exposes {machine_file['exposures']} masks over {machine_file['domain_pixels']} "
            f"pixels of {machine_file['pixel_mm']:g} mm; the writer makes no time estimate."
        )
    paragraphs = [Paragraph(tuple(head))]
    sent = figures.get("sent")
    if sent:
        paragraphs.append(Paragraph(_sent_sentence(sent)))
    return paragraphs


def _duration(seconds: float) -> str:
    """A duration in words: ``15 min``, ``1 h 12 min``, ``40 s``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    minutes = round(seconds / 60)
    return f"{minutes} min" if minutes < 60 else f"{minutes // 60} h {minutes % 60} min"


def _sent_sentence(sent: Mapping[str, Any]) -> Text:
    """The send in one sentence (a port, or a printer host)."""
    if "host" in sent:
        started = f"started; the host said {sent['state']}" if sent["started"] else "not started"
        return (
            "It was uploaded to ",
            Code(sent["host"]),
            f" ({sent['server']}), {sent['uploaded_bytes']} bytes, and {started}, "
            f"after {sent['seconds']:.1f} s.",
        )
    return (
        "It was sent to ",
        Code(sent["port"]),
        f": {sent['job_lines']} lines in {sent['seconds']:.1f} s, "
        f"{_count(sent['resent_lines'], 'line')} resent.",
    )


def _count(n: int, noun: str) -> str:
    """``no line``, ``1 line``, ``3 lines``."""
    return f"no {noun}" if n == 0 else f"{n} {noun}{'s' if n > 1 else ''}"


def _warnings(figures: Mapping[str, Any]) -> Text:
    """Warnings of the planning and the send, and features left out, in sentences."""
    warnings = [*figures.get("toolpath warnings", [])]
    if figures.get("sent"):
        warnings += figures["sent"].get("warnings", [])
    spans: list[Span] = []
    if warnings:
        spans.append(f"{_count(len(warnings), 'warning').capitalize()}: ")
        for k, warning in enumerate(warnings):
            spans += [*_spans(warning), "; " if k < len(warnings) - 1 else ". "]
    else:
        spans.append("No warnings. ")
    if figures.get("notice"):
        spans.append("Features were left out of the machine file on purpose (the first line).")
    else:
        spans.append("Every feature of the design is in the machine file.")
    return tuple(spans)


def _shapes_section(figures: Mapping[str, Any], folder: Path) -> Section:
    """A picture per target of the sheet beside it, and the meshes."""
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
        blocks.append(Figure(folder / shape["picture"], caption))
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
        Table(("surface", "area (design units²)"), tuple((n, _num(a)) for n, a in areas.items())),
    ]
    stops = solve["stop_counts"]
    if stops:
        blocks.append(Paragraph(("Where the solver stopped marching, and why:",)))
        blocks.append(
            Table(
                ("reason", "grid points"),
                tuple((_spans(reason), str(count)) for reason, count in stops.items()),
            )
        )
    blocks += [*_check_blocks(figures["check"]), *_figures(pictures)]
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
        ("solved area", (f"{_num(part['solved_area'])} {area}",)),
        ("kept of the solved area", (f"{part['kept_pct']:g} % ({_num(part['area'])} {area})",)),
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
        rows.append(("outline given", _spans(part["outline"])))
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


def _layers_section(figures: Mapping[str, Any]) -> Section:
    """How much of each target's curvature the layers program."""
    layers = figures["layers"]
    alone = {t["target"]: t for t in layers["metric alone"]["targets"]}
    rows = tuple(
        (
            name,
            f"{'formed' if alone[name]['formed'] else 'NOT formed'}, "
            f"{alone[name]['rms_pct']:.2f} % RMS"
            + (", mirror image" if alone[name]["mirror_image"] else ""),
            "yes" if weight > 0 else "no",
            f"{100 * max(0.0, layers['curvature_matched'][name]):.0f} %",
            f"{100 * layers['right_side'][name]:.0f} %",
        )
        for name, weight in layers["weights"].items()
    )
    limited = ", ".join(f"{100 * share:.0f} %" for share in layers["features_limited"])
    blocks = (
        Paragraph(
            (
                "The layers differ so that the sheet's natural curvature is that of the targets "
                "the metric alone misses (docs/layers.md):",
            )
        ),
        Table(
            (
                "target",
                "programmed by its metric alone",
                "curvature asked for",
                "of its curvature programmed",
                "of its points bent to its own side",
            ),
            rows,
        ),
        Paragraph(
            (
                f"Share of the points where a feature's range held its difference between the "
                f"layers back: {limited} (one per feature). Largest difference between the "
                f"layers' mean metric and the design's: {100 * layers['metric_error']:.2g} % "
                "(relative).",
            )
        ),
    )
    return Section("Layers", blocks)


def _fabrication_section(figures: Mapping[str, Any], preview: tuple[str, Path]) -> Section:
    """What the machine makes: print lines, channels or an exposure pattern."""
    picture = Figure(preview[1], preview[0])
    if "toolpath quality" in figures:
        return Section("Print lines", (*_print_lines(figures), picture))
    if "mould" in figures:
        return Section("Baromorph channels", (*_channels(figures), picture))
    return Section("Photoalignment pattern", (picture,))


def _print_lines(figures: Mapping[str, Any]) -> list[Block]:
    """The channels that carry the features, and the quality of every layer's lines."""
    channels = "; ".join(
        f"{features} as the {LABELS.get(parameter, parameter)}"
        for parameter, features in figures["channels"].items()
    )
    header = (
        "layer",
        "not covered",
        "overlap",
        "mean angle to the director (deg)",
        "print lines",
        "printing (mm)",
        "travel between lines (mm)",
    )
    rows = tuple(
        (
            str(k + 1),
            _pct(q["empty_fraction"]),
            _pct(q["mean_overlap"]),
            f"{q['mean_angle_error_deg']:.2f}",
            str(q["paths"]),
            _num(q["print_length_mm"]),
            _num(q["travel_between_lines_mm"]),
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
        ("channel width error, largest", (_pct(c["max_width_error"]),)),
        ("channel width error, mean", (_pct(c["mean_width_error"]),)),
        ("cuts across the channels measured", (str(c["width_samples"]),)),
        ("casting mould (STL)", _spans(figures["mould"])),
    )  # fmt: skip
    return [Facts(rows)]


def _machine_file_section(figures: Mapping[str, Any]) -> Section:
    """Every machine file written, its figures in words."""
    blocks = tuple(
        Paragraph(_spans(_sentence(summary.replace(" mm^3", " mm³"))))
        for summary in figures["exports"].values()
    )
    return Section("The machine file", blocks)


def _verify_section(figures: Mapping[str, Any]) -> Section:
    """The machine file read back: coverage, director and features per layer, notes."""
    verify = figures["verify"]
    own = verify["process"] == f"machine {verify['machine']}"
    process: Text = ("its own process",) if own else ("the process ", *_spans(verify["process"]))
    opening: Text = (
        Code(figures["machine file"]["file"]),
        " read back as ",
        Code(verify["machine"]),
        " reads it, with ",
        *process,
        "; placed by the ",
        *_spans(verify["placement"]),
        f"; on cells of {verify['cell_mm']:.3g} mm. Over the cells inside the part, every layer "
        "against its design (feature errors as a share of the feature's designed range):",
    )
    layers = verify["layers"] or [{"layer": 1, **verify}]
    features = [f"{f['feature']}, as the {_label(f['channel'])}," for f in layers[0]["features"]]
    header = (
        "layer",
        "not covered",
        "overlap",
        "director error, mean / 95th percentile (deg)",
        *(f"{name} error: RMS / 95th percentile" for name in features),
    )
    rows = tuple(
        (
            str(layer["layer"]),
            _pct(layer["empty_fraction"]),
            _pct(layer["mean_overlap"]),
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
    spans = [span for note in notes for span in (*_spans(_sentence(_words(note))), " ")]
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


def _num(value: float) -> str:
    """A figure to 4 significant digits, without an exponent below 10,000."""
    return f"{value:.4g}" if abs(value) < 1e4 else f"{value:.0f}"


def _pct(fraction: float) -> str:
    """A fraction as a percentage."""
    return f"{100 * fraction:.2f} %"


FORMATS = {"gcode": "G-code", "dxf": "DXF drawing", "laser": "laser patterns"}
"""Machine file formats in words."""


def _words(text: str) -> str:
    """``text`` with every process parameter's key in words (``print_speed_mm_s`` -> print
    speed (mm/s))."""
    for key, label in sorted(LABELS.items(), key=lambda item: -len(item[0])):
        text = re.sub(rf"\b{key}\b", label, text)
    return text


def _is_name(token: str) -> bool:
    """Whether a word is a name as written in a file or a command: it has an underscore,
    it is a path, or it is a dotted key or file name (``solver.tolerance``, ``sheet.gcode``)."""
    return (
        "_" in token
        or (token.count("/") > 1 or token[:1] == "/" or ("/" in token and "." in token))
        or re.fullmatch(r"[A-Za-z]\w+(\.\w{2,})+", token) is not None
    )


def _spans(text: str) -> Text:
    """``text`` with process parameters in words (:func:`_words`) and every name
    (:func:`_is_name`) as :class:`Code`."""
    text = _words(text)
    spans: list[Span] = []
    end = 0
    for match in re.finditer(r"[^\s(),;]+", text):
        name = match.group().rstrip(":.")
        if not _is_name(name):
            continue
        spans += [text[end : match.start()], Code(name)]
        end = match.start() + len(name)
    spans.append(text[end:])
    return tuple(s for s in spans if s != "")
