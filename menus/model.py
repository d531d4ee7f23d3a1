"""Radial menu trees as data: the file format, its validation, and the flattened form clients draw from.

A menu file (YAML) holds one tree:

    menu: {id: status, label: Status, controller: left, button: X, icon: info}
    items:
      - {id: status.hardware, label: Hardware, slot: left, icon: cpu,
         command: show_status, args: {which: hardware}}
      - {id: motion.play, label: Play, slot: bottom, icon: play, generate: gestures}
      - {id: speech.more, label: More, slot: right, icon: dots, submenu: [...]}

An item has exactly one of `command` (with `args`), `submenu` (a list of items) or `generate` (items made when
the menus are published: `gestures` from the gesture library, `emotions` from the robot model, `sentences` from
the text file named by `source`, relative to the menu file). A sentence may hold variables, filled in by the server
when it is said and in the menus' labels: {pupil}, {teacher} (SENTENCE_VARIABLES). Slots are left, top, right,
bottom (each at most once per level) or list (drawn in file order). Item ids are unique across every file.

A menu's `words` names the words its emotions say as they are shown, one file per language (emotion_words.txt stands
for emotion_words.<language>.txt, relative to the menu file), each line `emotion: words`. The reference language's
file says which emotions speak; every other language's names the same ones.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from client_protocol.files import load_model_file

from .commands import COMMANDS, Command

COMPASS = ("left", "top", "right", "bottom")
GENERATORS = ("gestures", "emotions", "sentences", "clips")
REFERENCE_LANGUAGE = "en"  # the sentence list whose lines name the items (speech.sentences.well_done) in every language
PACKAGED_DIR = Path(__file__).with_name("data")
# The variables a sentence may hold, as {name}: the server fills them in when the sentence is said.
SENTENCE_VARIABLES = {"pupil": "the pupil the robot attends to (their name), or the one the teacher picked",
                      "teacher": "the teacher's name (serve --teacher-name)"}
_VARIABLE = re.compile(r"\{([^{}]*)\}")


class MenuError(ValueError):
    """A menu file that cannot be used; the message names the file, the item and the problem."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Item(_Strict):
    id: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.\-]+$")
    label: str = Field(min_length=1)
    slot: Literal["left", "top", "right", "bottom", "list"] = "list"
    icon: str = ""
    command: Command | None = None
    args: dict[str, Any] = Field(default_factory=dict)
    submenu: list[Item] | None = None
    generate: Literal["gestures", "emotions", "sentences", "clips"] | None = None
    source: str | None = Field(None, description="the sentences file, for generate: sentences (sentences.txt stands "
                               "for sentences.<language>.txt, one per language)")

    @field_validator("command", mode="before")
    @classmethod
    def _known_command(cls, value: Any) -> Any:
        if isinstance(value, str) and value not in COMMANDS:
            raise ValueError(f"unknown command {value!r}; commands are {', '.join(sorted(COMMANDS))}")
        return value

    @model_validator(mode="after")
    def _one_kind(self) -> Item:
        kinds = [k for k in ("command", "submenu", "generate") if getattr(self, k) is not None]
        if len(kinds) != 1:
            raise ValueError(f"needs exactly one of command, submenu or generate (has {', '.join(kinds) or 'none'})")
        if self.command is not None:
            try:
                COMMANDS[self.command](**self.args)
            except ValidationError as exc:
                problems = "; ".join(f"{'.'.join(map(str, e['loc'])) or 'args'}: {e['msg']}" for e in exc.errors())
                raise ValueError(f"args of {self.command}: {problems}") from None
        elif self.args:
            raise ValueError("args are given but there is no command")
        if (self.generate == "sentences") != (self.source is not None):
            raise ValueError("generate: sentences needs source (a text file), and only it takes one")
        if self.submenu is not None:
            _check_slots(self.submenu)
        return self


class MenuInfo(_Strict):
    id: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.\-]+$")
    label: str = Field(min_length=1)
    controller: Literal["left", "right", "any"] = "any"
    button: str = ""
    icon: str = ""
    words: str | None = Field(None, description="the words this menu's emotions say, per language: "
                              "emotion_words.txt stands for emotion_words.<language>.txt (lines 'emotion: words')")


class MenuFile(_Strict):
    menu: MenuInfo
    items: list[Item] = Field(min_length=1)

    @model_validator(mode="after")
    def _slots(self) -> MenuFile:
        _check_slots(self.items)
        return self


def _check_slots(items: list[Item]) -> None:
    seen: dict[str, str] = {}
    for item in items:
        if item.slot in COMPASS:
            if item.slot in seen:
                raise ValueError(f"items {seen[item.slot]!r} and {item.id!r} both take slot {item.slot}")
            seen[item.slot] = item.id


def walk(items: list[Item], parent: str):
    """(parent id, position, item) for every item, depth first."""
    for position, item in enumerate(items):
        yield parent, position, item
        if item.submenu:
            yield from walk(item.submenu, item.id)


def read_sentences(path: Path) -> list[str]:
    """One sentence per line; blank lines and lines starting with # are skipped. MenuError names the file and the
    line of a variable that is not one of SENTENCE_VARIABLES."""
    out = []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        for name in _VARIABLE.findall(line):
            if name not in SENTENCE_VARIABLES:
                raise MenuError(f"{path}:{number}: unknown variable {{{name}}}; a sentence may hold "
                                f"{', '.join(f'{{{v}}}' for v in SENTENCE_VARIABLES)}")
        out.append(line.strip())
    return out


def fill_sentence(text: str, values: dict[str, str], *, keep_missing: bool = False) -> str:
    """`text` with its variables replaced by `values`. ValueError names a variable that is unknown or, unless
    keep_missing (a label: the variable stays as written), has no value now."""
    def value(match: re.Match[str]) -> str:
        name = match.group(1)
        if name not in SENTENCE_VARIABLES:
            raise ValueError(f"unknown variable {{{name}}} in {text!r}")
        if values.get(name):
            return values[name]
        if keep_missing:
            return match.group(0)
        raise ValueError(f"{{{name}}} has no value now ({SENTENCE_VARIABLES[name]}): {text!r} cannot be said")

    return _VARIABLE.sub(value, text)


def sentences_file(source: Path, language: str) -> Path:
    """The sentence list of `language` that `source` stands for: sentences.txt -> sentences.de.txt. English falls
    back to the plain file (a menu directory written before languages)."""
    path = source.with_name(f"{source.stem}.{language}{source.suffix}")
    if language == REFERENCE_LANGUAGE and not path.exists() and source.exists():
        return source
    return path


def _read_with_reference(source: Path, language: str, read: Callable[[Path], Any], kind: str,
                         what: str) -> tuple[Path, Any, Path, Any]:
    """The reference language's file of `source` and `language`'s, each read by `read`: (reference path, its
    contents, path, its contents). MenuError names a missing file."""
    reference_path, path = sentences_file(source, REFERENCE_LANGUAGE), sentences_file(source, language)
    try:
        return reference_path, read(reference_path), path, read(path)
    except FileNotFoundError as exc:
        raise MenuError(f"no {kind} for {language!r}: {exc.filename} is missing") from None
    except OSError as exc:
        raise MenuError(f"cannot read {what}: {exc}") from None


def language_sentences(source: Path, language: str) -> list[tuple[str, str]]:
    """(reference sentence, sentence in `language`) line by line: the items keep the reference's ids in every
    language, so autonomy rules and recordings name the same item whatever the robot speaks. MenuError names the
    file that is missing or does not match the reference line for line."""
    reference_path, reference, path, sentences = _read_with_reference(source, language, read_sentences,
                                                                      "sentence list", "sentences")
    if not reference:
        raise MenuError(f"{reference_path} holds no sentences")
    if len(sentences) != len(reference):
        raise MenuError(f"{path} holds {len(sentences)} sentences and {reference_path} {len(reference)}: each "
                        "language's list has the same sentences, line by line")
    return list(zip(reference, sentences))


def read_words(path: Path) -> dict[str, str]:
    """`emotion: words` per line; blank lines and lines starting with # are skipped. MenuError names the line."""
    words: dict[str, str] = {}
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        name, colon, text = line.partition(":")
        if not colon or not name.strip() or not text.strip():
            raise MenuError(f"{path}:{number}: write 'emotion: words' (got {line.strip()!r})")
        if name.strip() in words:
            raise MenuError(f"{path}:{number}: {name.strip()} has words twice")
        words[name.strip()] = text.strip()
    return words


def language_words(source: Path, language: str) -> dict[str, str]:
    """Emotion -> the words it says in `language`. The reference language's file says which emotions speak; MenuError
    names the file that is missing, or that lacks (or adds) an emotion of the reference's."""
    reference_path, reference, path, words = _read_with_reference(source, language, read_words, "emotion words",
                                                                  "emotion words")
    missing = [name for name in reference if name not in words]
    if missing:
        raise MenuError(f"{path} has no words for {', '.join(missing)} ({reference_path} has): add a line "
                        "'emotion: words' for each")
    extra = [name for name in words if name not in reference]
    if extra:
        raise MenuError(f"{path} has words for {', '.join(extra)}, which {reference_path} does not: each "
                        "language's file names the same emotions")
    return words


class LoadedMenu:
    def __init__(self, path: Path, data: MenuFile) -> None:
        self.path = path
        self.info = data.menu
        self.items = data.items


def _item_place(doc: Any) -> Callable[[tuple[Any, ...]], str]:
    """How an error's location reads in this menu file: the item's id (found in the raw document), then the field."""
    return lambda loc: _place(doc, list(loc))


def _place(doc: Any, loc: list[Any]) -> str:
    node, where, rest, previous = doc, "", loc, None
    for i, key in enumerate(loc):
        try:
            node = node[key]
        except (KeyError, IndexError, TypeError):
            break
        if previous in ("items", "submenu") and isinstance(key, int):
            where = f"item {node.get('id')!r}" if isinstance(node, dict) and node.get("id") else f"item #{key + 1}"
            rest = loc[i + 1:]
        elif key == "menu" and i == 0:
            where, rest = "menu", loc[1:]
        previous = key
    field = ".".join(str(k) for k in rest if not str(k).startswith("function-after"))
    return f"{where or 'file'}: {field}" if field else where or "file"


def load_menu_file(path: Path) -> LoadedMenu:
    data = load_model_file(MenuFile, path, error=MenuError, place=_item_place)
    if data.menu.words is not None:
        try:
            language_words(path.parent / data.menu.words, REFERENCE_LANGUAGE)
        except MenuError as exc:
            raise MenuError(f"{path}: menu words: {exc}") from None
    for _parent, _pos, item in walk(data.items, data.menu.id):
        if item.source is not None:
            source = path.parent / item.source
            try:
                language_sentences(source, REFERENCE_LANGUAGE)
                for other in sorted(source.parent.glob(f"{source.stem}.*{source.suffix}")):
                    read_sentences(other)  # every language's variables, at load
            except MenuError as exc:
                raise MenuError(f"{path}: item {item.id!r}: {exc}") from None
    return LoadedMenu(path, data)


def load_menus(directory: Path | None = None) -> list[LoadedMenu]:
    """Every *.yaml menu in `directory` (default: the packaged menus), checked together for unique ids."""
    directory = directory or PACKAGED_DIR
    files = sorted(directory.glob("*.yaml"))
    if not files:
        raise MenuError(f"{directory}: no menu files (*.yaml)")
    menus = [load_menu_file(f) for f in files]
    owner: dict[str, Path] = {}
    for menu in menus:
        for id_, _ in [(menu.info.id, None)] + [(item.id, None) for _p, _i, item in walk(menu.items, menu.info.id)]:
            if id_ in owner:
                other = "" if owner[id_] == menu.path else f" (also in {owner[id_]})"
                raise MenuError(f"{menu.path}: item {id_!r}: duplicate id{other}")
            owner[id_] = menu.path
    return menus
