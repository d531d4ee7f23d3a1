"""Radial menus as data: the packaged trees (menus/data/*.yaml), their file format and the command vocabulary."""

from .commands import COMMANDS, Command, MenuEntry
from .model import PACKAGED_DIR, Item, LoadedMenu, MenuError, load_menu_file, load_menus, read_sentences, walk
from .model import REFERENCE_LANGUAGE, SENTENCE_VARIABLES, fill_sentence, language_sentences, language_words, \
    sentences_file

__all__ = ["COMMANDS", "Command", "MenuEntry", "PACKAGED_DIR", "Item", "LoadedMenu", "MenuError", "load_menu_file", "load_menus",
           "read_sentences", "walk", "REFERENCE_LANGUAGE", "SENTENCE_VARIABLES", "fill_sentence", "language_sentences",
           "language_words", "sentences_file"]
