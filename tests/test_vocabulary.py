"""The typed vocabulary (client_protocol/vocabulary.py) stays the one spelling: the server's code compares against
its enum members, never against the strings they stand for, read from the source (an AST scan of vr_teleop_server/).

A string such as "accepted" or "supervised" means one thing only: compared against anywhere, it is flagged. Words
that other vocabularies share ("head" is also a pose stream, "operator" a role, "none" a compression, "server" a
sender) are flagged where the other side of the comparison names what they are (an owner, a part, a level, an
outcome...), and where a claim on the ownership arbiter or a question about a part passes them as strings.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterable
from pathlib import Path

from client_protocol.vocabulary import VOCABULARIES, Decision, Outcome

ROOT = Path(__file__).resolve().parent.parent
SERVER = ROOT / "vr_teleop_server"

VALUES = {m.value for kind in VOCABULARIES for m in kind}
SHARED = {"head", "voice", "face", "operator", "client", "trial", "gesture", "estop", "none", "autonomy", "server",
          "timeout", "robot", "teacher"}  # words other vocabularies use too
DISTINCT = VALUES - SHARED
# what the other side of a comparison names when a shared word there is one of these vocabularies'
CONTEXT = re.compile(r"\b(owners?|claimants?|claims?|parts?|decided_by|initiator)\b")
CLAIMS = {"claim", "release", "hold"}  # Ownership's methods taking a claimant first
ASKS = {"owner", "holder", "free"}  # Ownership's methods taking a part


def _strings(node: ast.expr) -> list[str]:
    """The string constants `node` is, or holds as a tuple, list or set literal."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, ast.Tuple | ast.List | ast.Set):
        return [s for element in node.elts for s in _strings(element)]
    return []


def spelled_out(files: Iterable[Path], root: Path) -> list[str]:
    """Each comparison against a vocabulary's string, and each string claimant or part given to the arbiter, as
    'file:line "word"'."""
    found = []
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            hits: list[str] = []
            if isinstance(node, ast.Compare):
                sides = [node.left, *node.comparators]
                for (a, b), op in zip(zip(sides, sides[1:]), node.ops):
                    if not isinstance(op, ast.Eq | ast.NotEq | ast.In | ast.NotIn):
                        continue
                    for this, other in ((a, b), (b, a)):
                        named = bool(CONTEXT.search(ast.unparse(other)))
                        hits += [s for s in _strings(this) if s in DISTINCT or s in VALUES and named]
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.args:
                if node.func.attr in CLAIMS and "owners" in ast.unparse(node.func.value):
                    hits += [s for s in _strings(node.args[0]) if s in VALUES]
                elif node.func.attr in ASKS and "owners" in ast.unparse(node.func.value):
                    hits += [s for s in _strings(node.args[0]) if s in VALUES]
            found += [f"{path.relative_to(root)}:{node.lineno} {s!r}" for s in hits]
    return found


def test_the_server_compares_against_the_enums_not_their_strings():
    files = sorted(SERVER.rglob("*.py"))
    assert len(files) > 100  # the scan sees the server
    found = spelled_out(files, ROOT)
    assert not found, ("compare against client_protocol.vocabulary's members (AutonomyLevel.SUPERVISED, "
                       "Outcome.ACCEPTED, Owner.OPERATOR, Part.HEAD...), not the strings they stand for:\n  "
                       + "\n  ".join(found))


def test_the_scan_finds_the_strings(tmp_path):
    """It flags what it forbids, and leaves the other vocabularies' words alone."""
    (tmp_path / "a.py").write_text(
        'if self.level == "teleoperated": pass\n'  # 1: a level
        'x = o.get("outcome") in ("accepted", "rejected")\n'  # 2: two outcomes
        'y = self.owners.owner(part) == "none"\n'  # 3: a shared word, about an owner
        'self.owners.claim("operator", parts)\n'  # 4: a claimant as a string
        'z = role == "operator" or stream == "head" or compression == "none"\n'  # 5: other vocabularies
        'w = self.owners.free(Part.HEAD) and self.level == AutonomyLevel.SUPERVISED\n'  # 6: the members
        'v = "dropped" != counter\n')  # 7: a distinct word, on the left
    assert spelled_out([tmp_path / "a.py"], tmp_path) == [
        "a.py:1 'teleoperated'", "a.py:2 'accepted'", "a.py:2 'rejected'", "a.py:3 'none'", "a.py:4 'operator'",
        "a.py:7 'dropped'"]


def test_a_member_is_its_string_on_the_wire():
    """What makes the enums safe on the wire: each member equals, hashes and serialises as its value."""
    import json

    for kind in VOCABULARIES:
        for member in kind:
            assert member == member.value and hash(member) == hash(member.value)
            assert json.dumps({member: member}) == json.dumps({member.value: member.value})
    assert [d.outcome for d in Decision] == [Outcome.ACCEPTED, Outcome.REJECTED, Outcome.FORBIDDEN]
