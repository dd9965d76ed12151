"""The verdict section of a run's page (:mod:`fabkit.plot.page_sections`), in words: which
targets the sheet forms and how it was simulated, the other verdicts on the same targets,
the machine file and the send in a sentence, and the warnings.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from fabkit.plot.page import (
    FORMATS,
    Block,
    Code,
    Paragraph,
    Section,
    Span,
    Text,
    as_sentence,
    as_spans,
)
from fabkit.progress import clock


def verdict_section(figures: Mapping[str, Any]) -> Section:
    """Which targets the sheet forms, the machine file, warnings and ignored features."""
    verdict = figures["verdict"]
    blocks: list[Block] = [Paragraph((as_sentence(verdict["headline"]),), "headline")]
    final = figures["verdicts"][-1] if figures["verdicts"] else {"what": "not simulated"}
    if figures["verdicts"]:
        blocks.append(Paragraph((_sheet_simulated(final, figures),)))
    if figures.get("prints"):
        blocks.append(Paragraph((_prints(figures["prints"]),)))
    for target in final.get("targets", ()):
        blocks.append(Paragraph((target["line"],), "formed" if target["formed"] else "missed"))
    if final["what"] == "as fabricated":
        designed = figures["as designed"]
        blocks.append(Paragraph((_compared("As designed", designed),)))
    blocks.extend(_machine_file_sentences(figures))
    blocks.append(Paragraph(_warnings(figures)))
    return Section("Verdict", tuple(blocks))


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
    width, height = figures["part"]["extent"]
    made = f"the part {width:.3g} x {height:.3g} mm, cut from a solved region "
    made += f"{figures['size_mm']:g} mm long"
    return (
        f"The sheet {verdict['what']} ({sheet}; {made}) was "
        f"simulated from flat to every target's stimulus, from {source}, from each of six "
        "starts (the flat sheet lifted by a dome up, a dome down, a saddle of either sign "
        "and two random bumps). A target is formed when, from every start, the simulation "
        "converged, the sheet is not the target's mirror image and it ends within the limit "
        "of the target (RMS distance after the best rigid motion, as a share of the patch "
        "diameter); the figures are the worst start's:"
    )


def _prints(prints: list[Mapping[str, Any]]) -> str:
    """The prints a ``--prints`` run judged, in one sentence."""
    count = len(prints)
    each = ". ".join(
        f"Print {k + 1} ({p['file']}"
        + (f", its lines shifted {k}/{count} of their spacing" if k else "")
        + f"): {p['headline']}"
        for k, p in enumerate(prints)
    )
    return (
        f"Judged over {count} prints (--prints {count}), equally good prints of the design "
        "with their errors elsewhere; a target is formed only when every print forms it, and "
        f"each target's figures below are its worst print's. {each}."
    )


def _compared(what: str, verdict: Mapping[str, Any]) -> str:
    """Another verdict on the same targets in one sentence."""
    shapes = ", ".join(
        f"{t['target']} {t['rms_pct']:.2f} % RMS{_missed(t)}" for t in verdict["targets"]
    )
    formed = "forms every target" if verdict["formed"] else "does NOT form every target"
    return f"{what}, the sheet {formed}: {shapes}."


def _missed(target: Mapping[str, Any]) -> str:
    """`` (not formed: ...why)`` for a target not formed, else "": how many of the starts
    ended as its mirror image, did not converge or ended beyond the limit."""
    if target["formed"]:
        return ""
    starts = target["starts"]
    counts = (
        ("its mirror image", sum(s["mirror_image"] for s in starts)),
        ("not converged", sum(not s["converged"] for s in starts)),
        ("beyond the limit", sum(s["rms_pct"] > target["limit_pct"] for s in starts)),
    )
    reasons = [f"{reason} from {n} of {len(starts)} starts" for reason, n in counts if n]
    return f" (not formed: {', '.join(reasons)})"


def _machine_file_sentences(figures: Mapping[str, Any]) -> list[Paragraph]:
    """The machine file in a sentence (its time and material where known), and the send."""
    machine_file = figures["machine file"]
    name = Code(machine_file["file"])
    head: list[Span] = ["The machine file ", name, " (", FORMATS[machine_file["format"]]]
    head += [" for ", Code(figures["machine"]), ")"]
    if "estimated_seconds" in machine_file:
        volume = machine_file["volume_mm3"]
        time = clock(machine_file["estimated_seconds"])
        head.append(
            f" prints {machine_file['print_length_mm'] / 1000:.3g} m of road in "
            f"{machine_file['lines']} lines ({machine_file['moves']} moves), in {time} "
            "(h:mm:ss, as the machine's planner runs its moves and dwells; homing and "
            f"heating not counted), with {volume:.4g} mm³ of material ({volume / 1000:.3g} mL)."
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
            spans += [*as_spans(warning), "; " if k < len(warnings) - 1 else ". "]
    else:
        spans.append("No warnings. ")
    if "NOT ENCODED" in figures.get("notice", ""):
        spans.append("Features were left out of the machine file on purpose (the first line).")
    else:
        spans.append("Every feature of the design is in the machine file.")
    return tuple(spans)
