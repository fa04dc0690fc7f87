"""The documentation stays short, linked, current, self-contained and free of project history.

README.md is a front page (at most 200 lines) with the test command .ci/run extracts; every
relative link and image in the user docs resolves to a file of the repository (section anchors
included); no page cites the specification kept outside the repository or sends users to the
folder beside the checkout, except where the reference data must be found (:data:`OUTSIDE_ALLOWED`);
no docstring, comment, message or config of the code cites that specification, and the package
names that folder only where it reads the reference data (:data:`CODE_OUTSIDE_ALLOWED`);
no page tells the project's history; docs/results.md and the README's caption of the main job are
exactly what docs/make_results.py writes from the committed result files; and the README's command
table names every ``neuralbrdf`` subcommand.
"""

from __future__ import annotations

import importlib.util
import json
import re
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: The user documentation: the front page, the docs pages and the READMEs of the script folders.
PAGES = sorted([README, ROOT / "export" / "README.md", ROOT / "benchmarks" / "README.md",
                *(ROOT / "docs").glob("*.md")])
MAX_README_LINES = 200
#: Words that tell the project's history instead of what the product does.
HISTORY = (
    r"\bstops? \d+", r"\bsince stop\b", r"\bthis stop\b", r"\bthis session\b", r"\bearlier session\b",
    r"\bprevious(ly)?\b", r"\buntil then\b", r"\bissue \d+", r"\bissue #\d+", r"\bthe issue'?s\b",
    r"\bwas the default\b", r"\bno longer\b", r"\bused to (be|promise|need)\b", r"\bround \d+\b",
    r"\bcommit [0-9a-f]{7,40}\b", r"\bfor the first time\b", r"\bthe first time\b", r"\bas then\b",
)
#: A citation of the specification outside the repository: its file name, or a section sign after
#: its name.  Users do not have that file; cite the docs page or the paper instead.
SPEC_CITATION = re.compile(r"\bSPEC(?:\.md\b|\s*§)")
#: The folder beside the checkout that holds the specification and the reference data.
OUTSIDE = re.compile(r"\.\./shared\b|/work/shared\b")
#: The only places of the user docs that name that folder, each for a reason: where the shipped
#: configs and study profiles look for the reference data.  Each must still be there.
OUTSIDE_ALLOWED = {
    "README.md": ("`../shared/data/{merl-nbrdf,rgl-nbrdf,abc-low2012}` relative to the folder",),
    "docs/study.md": ("those starting with `../shared/` are\n  relative to the repository root",),
}
#: The source files whose text users and maintainers read: the package, configs, scenes, scripts, tests.
SOURCES = sorted(
    path for folder in ("neuralbrdf", "configs", "export", "benchmarks", "tests", "examples") for path in
    (ROOT / folder).rglob("*") if path.suffix in {".py", ".yaml", ".xml", ".sh"} and path.name != "test_docs.py"
) + [ROOT / "train.py"]
#: The package's lines that name the folder beside the checkout, each because the code reads the
#: reference data there; docstrings and comments describe that data instead.
CODE_OUTSIDE_ALLOWED = {
    "neuralbrdf/study/profile.py": (
        'elif text.startswith("../shared"):',
        "starting with ``../shared`` are relative to the repository root, others to the profile file.",
    ),
}
LINK = re.compile(r"!?\[(?P<text>[^\]]*)\]\((?P<target>[^)\s]+)(?:\s+\"[^\"]*\")?\)")
HTML_LINK = re.compile(r"<(?:a|img)\s[^>]*(?:href|src)=\"(?P<target>[^\"]+)\"")
FENCE = re.compile(r"^(```|~~~)")


def _prose(path: Path) -> str:
    """The page without its fenced code blocks (commands there are not links)."""
    lines, inside = [], False
    for line in path.read_text(encoding="utf-8").splitlines():
        if FENCE.match(line.strip()):
            inside = not inside
            lines.append("")
            continue
        lines.append("" if inside else line)
    return "\n".join(lines)


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*]|<[^>]+>", "", heading).strip().lower()
    kept = "".join(c for c in text if c in " -_" or unicodedata.category(c)[0] in "LN")
    return kept.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    anchors, seen = set(), {}
    for line in _prose(path).splitlines():
        match = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if match:
            slug = _slug(match.group(1))
            count = seen.get(slug, 0)
            anchors.add(slug if count == 0 else f"{slug}-{count}")
            seen[slug] = count + 1
    return anchors


def _links(path: Path) -> list[tuple[str, str]]:
    """``(text, target)`` of every Markdown and HTML link or image of the page."""
    prose = _prose(path)
    return ([(m.group("text"), m.group("target")) for m in LINK.finditer(prose)]
            + [("", m.group("target")) for m in HTML_LINK.finditer(prose)])


def _make_results():
    spec = importlib.util.spec_from_file_location("make_results", ROOT / "docs" / "make_results.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_readme_is_a_front_page_of_at_most_200_lines():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines; move detail into docs/"


def test_the_readme_holds_the_test_command_that_ci_extracts():
    text = README.read_text(encoding="utf-8")
    block = re.search(r"<!-- test-command -->\n```bash\n(?P<command>[^\n]+)\n```\n<!-- /test-command -->", text)
    assert block, "README.md needs the test command as one bash block between the test-command markers"
    command = block.group("command")
    assert "pip install -c constraints.txt" in command and command.rstrip().endswith("-m pytest")
    assert text.count("<!-- test-command -->") == 1 and text.count("<!-- /test-command -->") == 1


@pytest.mark.skipif(not (ROOT / ".git").exists(), reason="not a git checkout: nothing to clone")
def test_ci_runs_the_test_command_in_a_fresh_clone_with_no_reference_data_beside_it():
    """A fresh clone failed the README's test command while CI, with ../shared beside its
    checkout, passed: .ci/run runs it in .ci/fresh-clone too, a clone of HEAD in a bare folder."""
    import subprocess

    assert '.ci/fresh-clone $(printf %q "$test_command")' in (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    probe = 'pwd; git rev-parse HEAD; test -f README.md && test ! -e ../shared && test "$(ls ..)" = neuralbrdf'
    run = subprocess.run([str(ROOT / ".ci" / "fresh-clone"), probe], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    folder, head = run.stdout.split()
    head_here = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    assert head == head_here and not Path(folder).exists()  # HEAD, cloned, then removed
    assert subprocess.run([str(ROOT / ".ci" / "fresh-clone"), "exit 7"], capture_output=True).returncode == 7


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_and_image_resolves(page):
    broken = []
    for _, target in _links(page):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto: ...
            continue
        path_part, _, anchor = target.partition("#")
        destination = (page.parent / path_part).resolve() if path_part else page
        if not destination.exists() or ROOT not in (destination, *destination.parents):
            broken.append(f"{target}: no such file in the repository")
        elif anchor and destination.suffix == ".md" and anchor not in _anchors(destination):
            broken.append(f"{target}: no heading with that anchor")
    assert not broken, f"{page.relative_to(ROOT)}: " + "; ".join(broken)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_picture_says_what_it_shows(page):
    text = page.read_text(encoding="utf-8")
    for match in re.finditer(r"!\[(?P<alt>[^\]]*)\]\((?P<target>[^)]+)\)", text):
        assert match.group("alt").strip(), f"{page.name}: image {match.group('target')} has no alt text"
        after = text[match.end():].lstrip("\n")
        assert after and not after.startswith("!["), (
            f"{page.name}: image {match.group('target')} needs a description beside it")


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_table_row_has_the_header_s_cells(page):
    """A ``|`` inside a code span splits a Markdown table cell (write it ``\\|``), and a text line
    right after a table is read as one more row (leave a blank line)."""
    width, bad = None, []
    for number, line in enumerate(_prose(page).splitlines(), 1):
        if not line.startswith("|"):
            if width is not None and line.strip():
                bad.append(f"line {number}: text right after a table")
            width = None
            continue
        cells = len(re.findall(r"(?<!\\)\|", line))
        width = cells if width is None else width
        if cells != width:
            bad.append(f"line {number}: {cells - 1} cells, header {width - 1}")
    assert not bad, f"{page.relative_to(ROOT)}: " + "; ".join(bad)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_page_tells_the_project_history(page):
    text = page.read_text(encoding="utf-8")
    found = [m.group(0) for pattern in HISTORY for m in re.finditer(pattern, text, flags=re.IGNORECASE)]
    assert not found, f"{page.relative_to(ROOT)} tells history: {found}; state what the product does"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_page_points_outside_the_repository(page):
    """Users have the repository, not the specification or the folder beside the checkout."""
    relative = str(page.relative_to(ROOT))
    text = page.read_text(encoding="utf-8")
    for allowed in OUTSIDE_ALLOWED.get(relative, ()):
        assert allowed in text, f"{relative}: stale entry of OUTSIDE_ALLOWED: {allowed!r}"
        text = text.replace(allowed, "")
    found = [m.group(0) for pattern in (SPEC_CITATION, OUTSIDE) for m in pattern.finditer(text)]
    assert not found, (f"{relative} points outside the repository: {found}; cite the docs page "
                       "(docs/formats.md#conventions, …) or the paper, and describe reference data by what it is")


def test_no_source_file_cites_the_specification():
    found = [f"{path.relative_to(ROOT)}:{number}" for path in SOURCES
             for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
             if SPEC_CITATION.search(line)]
    assert SOURCES and not found, f"cite the docs page (docs/formats.md#onnx-model-files, …) instead: {found}"


def test_the_package_names_the_folder_beside_the_checkout_only_to_read_the_reference_data():
    found = []
    for path in sorted((ROOT / "neuralbrdf").rglob("*.py")):
        relative = str(path.relative_to(ROOT))
        lines = path.read_text(encoding="utf-8").splitlines()
        allowed = CODE_OUTSIDE_ALLOWED.get(relative, ())
        for line in allowed:
            assert any(line in text for text in lines), f"{relative}: stale entry of CODE_OUTSIDE_ALLOWED: {line!r}"
        found += [f"{relative}:{number}" for number, text in enumerate(lines, 1)
                  if OUTSIDE.search(text) and not any(line in text for line in allowed)]
    assert not found, f"describe the reference data by what it is (README.md), not by its folder: {found}"


def test_the_outside_checks_find_what_they_are_for():
    for sample in ("(SPEC §6)", "SPEC §4.2–4.3", "``SPEC.md`` §1", "`../shared/SPEC.md`", "read ../shared/data",
                   "/work/shared/data/merl-nbrdf"):
        assert SPEC_CITATION.search(sample) or OUTSIDE.search(sample), sample
    for sample in ("SPECTRAL_NLB", 'raw[:4] != b"SPEC"', "the shared code", "docs/formats.md#conventions"):
        assert not (SPEC_CITATION.search(sample) or OUTSIDE.search(sample)), sample


def test_the_history_check_finds_history():
    """The patterns above catch the phrasing they are for (a check that cannot fail is no check)."""
    samples = ["Since stop 14 the default", "the issue's targets", "previously 0.02", "in this session",
               "until then it was", "issue 11's run", "was the default"]
    for sample in samples:
        assert any(re.search(p, sample, flags=re.IGNORECASE) for p in HISTORY), sample


def test_results_page_is_generated_from_the_committed_result_files():
    expected = _make_results().build()
    actual = (ROOT / "docs" / "results.md").read_text(encoding="utf-8")
    assert actual == expected, "docs/results.md is out of date: run python docs/make_results.py"


def test_the_readme_caption_is_written_from_the_main_job_scores():
    """The numbers under the README's picture are those of the committed evaluation.json."""
    make_results = _make_results()
    text = README.read_text(encoding="utf-8")
    assert make_results.readme_with_caption(text) == text, (
        "README.md's caption of the main job is out of date: run python docs/make_results.py")
    scores = json.loads((ROOT / make_results.MAIN_JOB).read_text(encoding="utf-8"))
    stale = text.replace(f"p95 {scores['image_delta_e2000_p95']:.2f}", "p95 9.99")
    assert stale != text and make_results.readme_with_caption(stale) == text


def test_the_readme_command_table_names_every_subcommand():
    from neuralbrdf.cli.main import build_parser

    parser = build_parser()
    commands = next(a for a in parser._actions if a.dest == "command").choices
    text = README.read_text(encoding="utf-8")
    missing = [name for name in commands if f"`neuralbrdf {name}" not in text and f"`{name}`" not in text]
    assert not missing, f"README.md's command table lacks: {missing}"


def test_the_slug_follows_github():
    assert _slug("The latent prior's weight") == "the-latent-priors-weight"
    assert _slug("Latent fit (RGB NLB)") == "latent-fit-rgb-nlb"
    assert _slug("`metrics.json`") == "metricsjson"
    assert _slug("Where users look: the held-out ten rendered") == "where-users-look-the-held-out-ten-rendered"
    assert _slug("`nlb_spectral` fit") == "nlb_spectral-fit"


def test_the_spectral_nlb_benchmark_file_becomes_tables():
    """benchmarks/spectral_nlb.json is not always committed: its tables are checked on a small file."""
    data = {"spectral_args": [], "groups": {"virtual DS1": {
        "materials": {"gold": {"nlb_spectral": {"hemisphere_logcos_rmse": 0.01, "image_delta_e2000_mean": 0.5},
                               "abc": {"failed": "non_finite_loss"}}},
        "summary": {"failed": {"nlb_spectral": 0, "abc": 1},
                    "hemisphere_logcos_rmse": {"materials": 1, "median": {"nlb_spectral": 0.01, "abc": 0.02},
                                               "nlb_spectral_beats": {"abc": 1.0}}}}}}
    text = "\n".join(_make_results().spectral_nlb_tables(data))
    assert "| gold | 0.0100 / 0.50 | failed |" in text
    assert "the spectral NLB beats `abc` on 100% of them" in text and "failed fits: `abc` 1" in text
