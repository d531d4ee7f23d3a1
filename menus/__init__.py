"""Radial menus as data: the packaged trees (menus/data/*.yaml), their file format and the command vocabulary."""

from .commands import COMMANDS
from .model import PACKAGED_DIR, Item, LoadedMenu, MenuError, load_menu_file, load_menus, read_sentences, walk

__all__ = ["COMMANDS", "PACKAGED_DIR", "Item", "LoadedMenu", "MenuError", "load_menu_file", "load_menus",
           "read_sentences", "walk"]
