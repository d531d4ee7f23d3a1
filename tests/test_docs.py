"""The documentation site: MkDocs' strict build passes (no broken link, missing page or wrong anchor), the generated
reference pages hold everything their sources define, and every picture the docs show exists.

One build per module (a few seconds), run as `make docs` runs it, into a temporary directory; the checks read the
built HTML, so they test what a reader gets.
"""

from __future__ import annotations

import argparse
import html
import os
import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import pytest

from client_protocol.definitions import MESSAGES, SERVICES
from client_protocol.interface import ENDPOINTS
from client_protocol.registry import normalize_type_name, parse_definition
from client_protocol.vocabulary import VOCABULARIES
from vr_teleop_server.cli import build_parser

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
# The site's agreed layout: every reader's way in has its page.
LAYOUT = {"index.md", *(f"guides/{p}.md" for p in (
    "teacher", "dashboard", "unity-rossharp", "recordings-replays", "studies", "questionnaires", "real-robot",
    "qtrobot-ros1", "qtrobot-v3", "deployment", "security", "contributing")),
    *(f"reference/{p}.md" for p in ("protocol", "cli", "configuration", "python-api")),
    "explanation/architecture.md", "explanation/performance.md"}


class Sections(HTMLParser):
    """The text of a page's article, cut at each h2/h3/h4: {heading text: text under it, heading included}."""

    def __init__(self) -> None:
        super().__init__()
        self.sections: dict[str, str] = {}
        self._heading: str | None = None
        self._in_heading = False
        self._current = "(top)"
        self._buffer: list[str] = []
        self.images: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag in ("h1", "h2", "h3", "h4"):
            self._flush()
            self._in_heading, self._heading_text = True, []
        if tag == "img":
            self.images += [v for k, v in attrs if k == "src" and v]

    def handle_endtag(self, tag: str) -> None:
        if tag in ("h1", "h2", "h3", "h4") and self._in_heading:
            self._in_heading = False
            self._current = "".join(self._heading_text).replace("¶", "").strip()

    def handle_data(self, data: str) -> None:
        if self._in_heading:
            self._heading_text.append(data)
        self._buffer.append(data)

    def _flush(self) -> None:
        self.sections[self._current] = self.sections.get(self._current, "") + "".join(self._buffer)
        self._buffer = []

    def close(self) -> None:
        super().close()
        self._flush()


def read_page(site: Path, page: str) -> Sections:
    parser = Sections()
    parser.feed((site / page / "index.html").read_text(encoding="utf-8"))
    parser.close()
    return parser


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(ROOT / "mkdocs.yml"),
         "--site-dir", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=300, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert done.returncode == 0, f"mkdocs build --strict failed:\n{done.stderr[-4000:]}"
    return out


def test_the_strict_build_makes_every_page_of_the_nav(site):
    import yaml

    config = yaml.load((ROOT / "mkdocs.yml").read_text(), Loader=yaml.BaseLoader)

    def pages(entries):
        for entry in entries:
            value = next(iter(entry.values())) if isinstance(entry, dict) else entry
            yield from pages(value) if isinstance(value, list) else [value]

    listed = list(pages(config["nav"]))
    assert len(listed) == len(set(listed))
    assert LAYOUT <= set(listed), f"pages of the agreed layout missing from the nav: {sorted(LAYOUT - set(listed))}"
    for page in listed:
        built = site / (page[:-3] + "/index.html" if page != "index.md" else "index.html")
        assert built.is_file(), f"{page} is in the nav but was not built"
        assert (DOCS / page).is_file()


@pytest.mark.parametrize("breakage", [
    "a link to [a page that does not exist](missing.md)",
    "a link to [an anchor that does not exist](other.md#no-such-heading)",
    "a picture that does not exist: ![camera](images/missing.webp)",
])
def test_the_sites_strict_settings_fail_a_broken_link_anchor_or_picture(tmp_path, breakage):
    """The site's own validation settings, on a two-page site: its sound version builds, a broken one does not."""
    import yaml

    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "other.md").write_text("# Other\n\n## A heading\n")
    small = {key: config[key] for key in ("theme", "validation", "markdown_extensions", "strict")}
    small.update(site_name="check", docs_dir=str(docs), nav=["index.md", "other.md"],
                 hooks=[str(ROOT / hook) for hook in config["hooks"]])
    (tmp_path / "mkdocs.yml").write_text(yaml.safe_dump(small))

    def build(text: str) -> subprocess.CompletedProcess:
        (docs / "index.md").write_text(f"# Home\n\n{text}\n")
        return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--site-dir", str(tmp_path / "site")],
                              cwd=tmp_path, capture_output=True, text=True, timeout=300,
                              env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})

    assert build("[A heading](other.md#a-heading)").returncode == 0
    broken = build(breakage)
    assert broken.returncode != 0 and "WARNING -  Doc file 'index.md' contains a link" in broken.stderr, broken.stderr


def test_the_protocol_page_has_every_endpoint_with_its_type_direction_and_rate(site):
    page = read_page(site, "reference/protocol")
    summary = page.sections["Summary"]
    for endpoint in ENDPOINTS:
        type_name = normalize_type_name(endpoint.type)
        text = page.sections.get(endpoint.name)
        assert text is not None, f"{endpoint.name} has no section on the protocol page"
        assert type_name in text and endpoint.name in summary
        assert {"publish": "publishes", "subscribe": "subscribes", "call": "calls"}[endpoint.direction] in text
        assert endpoint.rate in text
        assert html.unescape(endpoint.doc.split(".")[0]) in text
        # who may use it: a spectator only reads (subscribes, and calls read-only services)
        roles = re.search(r"who may use it: ([a-z, ]+)", text).group(1)
        assert "supervisor" in roles
        if endpoint.direction == "publish":
            assert "spectator" not in roles
        if endpoint.direction == "subscribe":
            assert roles.split(", ") == ["operator", "supervisor", "spectator"]


def test_the_protocol_page_lists_every_vocabulary_with_its_values(site):
    text = read_page(site, "reference/protocol").sections["Vocabularies"]
    text = text[text.index("What they name"):]  # the table, after its header
    starts = [text.index(f"{kind.__name__}") for kind in VOCABULARIES]  # the rows, in the enums' order
    for kind, start, end in zip(VOCABULARIES, starts, starts[1:] + [len(text)]):
        assert all(member.value in text[start:end] for member in kind), (kind.__name__, text[start:end])


def test_the_protocol_page_defines_every_type_it_names_with_its_fields(site):
    page = read_page(site, "reference/protocol")
    definitions = {**MESSAGES, **SERVICES}
    todo = [normalize_type_name(e.type) for e in ENDPOINTS]
    seen = set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        text = page.sections.get(name)
        assert text is not None, f"type {name} has no section on the protocol page"
        for half in definitions[name].split("---"):
            for f in parse_definition(name, half).fields:
                assert re.search(rf"\b{f.name}\b", text), f"{name}.{f.name} missing"
                if "/" in f.type:
                    todo.append(f.type)
    assert len(seen) >= 20


def parsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ("vr-teleop",)):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from parsers(sub, path + (name,))


def test_the_cli_page_has_every_subcommand_and_option(site):
    page = read_page(site, "reference/cli")
    found = list(parsers(build_parser()))
    assert len(found) > 12  # the command, its subcommands, and the questionnaires' template/score
    for path, parser in found:
        text = page.sections.get(" ".join(path))
        assert text is not None, f"{' '.join(path)} has no section on the CLI page"
        for action in parser._actions:
            for option in action.option_strings:
                assert option in text, f"{' '.join(path)} {option} missing"
            if action.choices is not None:
                for choice in action.choices:
                    assert str(choice) in text, f"{' '.join(path)}: {choice} missing"


def model_keys(model) -> set[str]:
    schema = model.model_json_schema()
    return {key for d in [schema, *schema.get("$defs", {}).values()] for key in d.get("properties", {})}


def test_the_configuration_page_has_every_key_of_every_file(site):
    from menus.commands import COMMANDS
    from menus.model import MenuFile
    from vr_teleop_server.features.motivation import MotivationConfig
    from vr_teleop_server.questionnaires.instrument import Instrument
    from vr_teleop_server.study.classroom_file import ClassroomStudy
    from vr_teleop_server.study.studyfile import Study
    from vr_teleop_server.teleop import TeleopSettings

    page = read_page(site, "reference/configuration")
    text = "".join(page.sections.values())
    for model in (TeleopSettings, MenuFile, Study, ClassroomStudy, MotivationConfig, Instrument):
        for key in model_keys(model):
            assert re.search(rf"\b{key}\b", text), f"{model.__name__}: {key} missing from the configuration page"
    for command, args in COMMANDS.items():
        assert command in text and all(key in text for key in model_keys(args))


def test_the_python_api_page_renders_the_robot_interface_and_scorers_from_their_docstrings(site):
    from vr_teleop_server.questionnaires import score_qam
    from vr_teleop_server.robot.interface import Robot

    text = "".join(read_page(site, "reference/python-api").sections.values())
    for name in Robot.__abstractmethods__:
        assert name in text
    for fn in (Robot.set_joint_targets, score_qam):
        if fn.__doc__:
            assert " ".join(fn.__doc__.split()[:6]) in " ".join(text.split())
    for name in ("Decision", "ActionModule", "Perception", "score_sus", "score_tlx", "score_godspeed"):
        assert name in text


IMAGE_LINK = re.compile(r"!\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)|<img[^>]*\ssrc=\"([^\"]+)\"")


def test_every_picture_the_docs_and_readme_show_exists(site):
    pictures = 0
    for md in [ROOT / "README.md", *DOCS.rglob("*.md")]:
        for match in IMAGE_LINK.finditer(md.read_text(encoding="utf-8")):
            target = match.group(1) or match.group(2)
            if re.match(r"[a-z]+:", target):
                continue
            assert (md.parent / target.split("#")[0]).resolve().is_file(), f"{md.relative_to(ROOT)}: {target}"
            pictures += 1
    for built in site.rglob("*.html"):
        parser = Sections()
        parser.feed(built.read_text(encoding="utf-8"))
        for src in parser.images:
            if not re.match(r"[a-z]+:", src):
                assert (built.parent / src).resolve().is_file(), f"{built.relative_to(site)}: {src}"
    assert pictures >= 1


def test_the_screenshots_are_small_pictures():
    images = sorted((DOCS / "images").iterdir())
    assert images
    for image in images:
        assert image.suffix in (".png", ".webp"), image.name
        assert image.stat().st_size < 400_000, f"{image.name} is {image.stat().st_size} bytes"
