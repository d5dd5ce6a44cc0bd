"""The documents' links: every relative link and image in README.md and docs/ names a file or folder of the
repository (a checkout's, so a renamed or removed file shows here, not to a reader)."""

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md"), *(ROOT / "scripts").glob("*.md")])
# [text](target) and ![alt](target), the target up to a space (a title) or the closing parenthesis;
# <img src="target">; reference definitions [name]: target
INLINE = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HTML = re.compile(r"<img[^>]*\bsrc=\"([^\"]+)\"", re.I)
REFERENCE = re.compile(r"^\s*\[[^\]]+\]:\s*(\S+)", re.M)
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def links(text: str) -> list[str]:
    """The link and image targets of markdown ``text``, code blocks and inline code left out."""
    text = FENCE.sub("", text)
    text = re.sub(r"`[^`\n]*`", "", text)
    return [m.group(1) for rx in (INLINE, HTML, REFERENCE) for m in rx.finditer(text)]


def test_links_are_read_from_markdown_as_written():
    text = ("See [the spec](../SPEC.md#rules), ![a plot](plots/a.png \"title\"), <img src=\"b.png\" width=3>,\n"
            "[a [nested] name](c.md), `[not](code.md)`, [web](https://x.org/a).\n"
            "```\n[in](fence.md)\n```\n[ref]: d/e.md\n")
    assert links(text) == ["../SPEC.md#rules", "plots/a.png", "c.md", "https://x.org/a", "b.png", "d/e.md"]


def _relative(target: str) -> bool:
    return not re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) and not target.startswith("#")


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_and_image_exists(doc):
    missing = []
    for target in links(doc.read_text()):
        if not _relative(target):
            continue
        path = (doc.parent / target.split("#")[0].split("?")[0]).resolve()
        if not path.exists():
            missing.append(target)
    assert not missing, f"{doc.relative_to(ROOT)}: links to missing files: {missing}"


def test_scripts_readme_lists_every_script_and_no_other():
    text = (ROOT / "scripts" / "README.md").read_text()
    named = set(re.findall(r"`([\w.-]+\.(?:py|sh))`", text))
    present = {p.name for p in (ROOT / "scripts").iterdir() if p.suffix in (".py", ".sh")}
    assert present - named == set(), f"scripts/README.md does not list {sorted(present - named)}"
    assert named - present == set(), f"scripts/README.md lists missing scripts {sorted(named - present)}"
