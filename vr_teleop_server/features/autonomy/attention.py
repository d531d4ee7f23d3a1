"""Where the robot looks when nobody moves its head: scoring and hysteresis after LuxAI's human_attention
behaviour, with a voice as the salient event (a pupil who starts speaking takes the attention after the
confirmation time, whatever the minimum focus). Sans I/O: `Attention.update(now, candidates)` is called at the
tracking rate with what perception holds, and returns where the head should point, in the robot's base frame.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass
from pathlib import Path

import yaml
from client_protocol.registry import describe_validation_error
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

DEFAULT_CONFIG = Path(__file__).with_name("data") / "attention.yaml"


class AttentionConfig(BaseModel):
    """LuxAI's figures are the defaults (reference/autonomy.md)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    rate_hz: float = Field(10.0, gt=0, le=50, description="tracking (and control tick) rate")
    min_distance_m: float = Field(0.35, ge=0, description="nearer than this is not a candidate")
    max_distance_m: float = Field(3.0, gt=0, description="farther than this is not a candidate")
    min_focus_s: float = Field(4.0, ge=0, description="a focus is kept at least this long (a voice excepted)")
    max_focus_s: float = Field(8.0, gt=0, description="after this, a candidate within fair_turn_margin takes over")
    switch_lead: float = Field(0.12, ge=0, le=1, description="score lead a challenger needs...")
    confirm_s: float = Field(0.8, ge=0, description="...held this long; also how long a new voice must last")
    fair_turn_margin: float = Field(0.08, ge=0, le=1)
    lost_grace_s: float = Field(0.8, ge=0, description="a focus lost for less than this is kept")
    smoothing: float = Field(0.45, gt=0, le=1, description="exponential smoothing of the target (alpha)")
    max_speed_deg_s: float = Field(60.0, gt=0, le=90, description="the head's direction changes at most this fast")
    idle_s: float = Field(5.0, ge=0, description="nobody there this long: glance around...")
    glance_interval_s: float = Field(5.0, gt=0, description="...every this many seconds")
    glance_y_m: float = Field(1.0, ge=0, description="a glance looks at y in -glance_y_m..glance_y_m...")
    glance_x_m: float = Field(2.0, gt=0, description="...at this distance ahead...")
    glance_z_m: float = Field(0.65, description="...and this height above the robot's base")
    eye_height_m: float = Field(0.6, description="the head camera's height above the base (for pitch)")
    release_grace_s: float = Field(1.0, ge=0, description="after a part is given back, autonomy waits this long")
    client_grace_s: float = Field(5.0, ge=0, le=600, description="a LuxAI API client owns what it commands until "
                                  "this long after its last command")
    face_height_m: float = Field(0.25, gt=0, description="a face's height, to tell a face's distance from its box")
    match_deg: float = Field(12.0, gt=0, description="a voice this close to a face is that face's")

    @model_validator(mode="after")
    def _ordered(self) -> AttentionConfig:
        if self.min_distance_m >= self.max_distance_m:
            raise ValueError("min_distance_m must be below max_distance_m")
        if self.min_focus_s > self.max_focus_s:
            raise ValueError("min_focus_s must not exceed max_focus_s")
        return self


def load_config(path: Path | None) -> AttentionConfig:
    """The attention configuration file (YAML mapping), refused by name with what is wrong."""
    path = path or DEFAULT_CONFIG
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
        return AttentionConfig.model_validate(data)
    except ValidationError as exc:
        raise ValueError(f"attention configuration {path}: {describe_validation_error(exc)}") from None
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"attention configuration {path}: {exc}") from None


@dataclass(frozen=True)
class Candidate:
    """A person perception holds now. yaw/pitch: direction in the base frame, degrees (yaw + left, pitch + down,
    as the head's joints). distance: metres, None when unknown (a voice alone). facing 0..1. speaking_since: when
    their current speech began (the server's monotonic clock), None when silent."""

    key: str
    yaw: float
    pitch: float = 0.0
    distance: float | None = None
    facing: float = 1.0
    speaking_since: float | None = None
    has_face: bool = True


@dataclass(frozen=True)
class Target:
    """Where the head should point now (already smoothed and speed-limited) and why."""

    source: str  # face, voice, both, glance
    key: str  # the candidate's key ("" for a glance)
    yaw: float
    pitch: float
    score: float


def score(c: Candidate, cfg: AttentionConfig) -> float | None:
    """LuxAI's score: 0.6 facing + 0.4 proximity; with voice activity 0.5 / 0.3 / 0.2. None: not a candidate."""
    if c.distance is None:
        proximity = 0.5  # a voice heard but not seen: somewhere in the room
    elif not cfg.min_distance_m <= c.distance <= cfg.max_distance_m:
        return None
    else:
        proximity = 1.0 - c.distance / cfg.max_distance_m
    facing = min(1.0, max(0.0, c.facing))
    if c.speaking_since is not None:
        return 0.5 * facing + 0.3 * proximity + 0.2
    return 0.6 * facing + 0.4 * proximity


class Attention:
    """One focus at a time, with LuxAI's hysteresis; the output direction moves at most max_speed_deg_s."""

    def __init__(self, cfg: AttentionConfig, *, yaw_limits: tuple[float, float] = (-60.0, 60.0),
                 pitch_limits: tuple[float, float] = (-15.0, 25.0), seed: int | None = None) -> None:
        self.cfg = cfg
        self.yaw_limits = yaw_limits
        self.pitch_limits = pitch_limits
        self._rng = random.Random(seed)
        self.focus: str | None = None
        self._focus_since = 0.0
        self._focus_seen = 0.0  # when the focus was last among the candidates
        self._goal: tuple[float, float] | None = None  # smoothed goal direction
        self._challenger: tuple[str, float] | None = None  # (key, leading since)
        self._nobody_since: float | None = None
        self._next_glance = 0.0
        self._glance: tuple[float, float] | None = None
        self.out: tuple[float, float] | None = None  # the direction last returned
        self._last: float | None = None
        self._source = ""
        self._score = 0.0

    def reseed(self, seed: int) -> None:
        """The glances' draws from `seed` (a study's run: the same seed glances alike)."""
        self._rng.seed(seed)

    def reset(self, here: tuple[float, float] | None) -> None:
        """Start again from the head's current direction (after something else moved it)."""
        self.out = here
        self._goal = None
        self._last = None

    def update(self, now: float, candidates: list[Candidate]) -> Target | None:
        cfg = self.cfg
        scored = {c.key: (c, s) for c in candidates if (s := score(c, cfg)) is not None}
        self._choose(now, scored)
        if self.focus is not None:
            self._nobody_since = None
            self._glance = None
            if self.focus in scored:
                c, s = scored[self.focus]
                goal = (c.yaw, c.pitch)
                self._source = ("both" if c.has_face else "voice") if c.speaking_since is not None else "face"
                self._score = s
            else:  # within the lost grace: keep looking where they were
                goal = self._goal or (0.0, 0.0)
        else:
            goal = self._idle(now)
            if goal is None:
                self._last = now
                return None
        return self._move(now, goal)

    # ---- choosing the focus -----------------------------------------------------------------------------------
    def _choose(self, now: float, scored: dict[str, tuple[Candidate, float]]) -> None:
        cfg = self.cfg
        if self.focus is not None:
            if self.focus in scored:
                self._focus_seen = now
            elif now - self._focus_seen >= cfg.lost_grace_s:
                self.focus = None
        if not scored:
            self._challenger = None
            return
        if self.focus is None:
            speakers = [k for k, (c, _) in scored.items() if c.speaking_since is not None]
            best = max(speakers or scored, key=lambda k: scored[k][1])
            self._switch(now, best)
            return
        current = scored.get(self.focus)
        # a voice is the salient event: a speaker away from the focus takes it once confirmed
        if current is None or current[0].speaking_since is None:
            speakers = [(c.speaking_since, k) for k, (c, _) in scored.items()
                        if k != self.focus and c.speaking_since is not None
                        and now - c.speaking_since >= cfg.confirm_s]
            if speakers:
                self._switch(now, max(speakers)[1])  # the newest confirmed speaker
                return
        if current is None:
            return
        focus_score = current[1]
        held = now - self._focus_since
        others = [(s, k) for k, (_, s) in scored.items() if k != self.focus]
        if not others or held < cfg.min_focus_s:
            self._challenger = None
            return
        best_score, best = max(others)
        if best_score >= focus_score + cfg.switch_lead:
            if self._challenger is None or self._challenger[0] != best:
                self._challenger = (best, now)
            elif now - self._challenger[1] >= cfg.confirm_s:
                self._switch(now, best)
            return
        self._challenger = None
        if held >= cfg.max_focus_s and best_score >= focus_score - cfg.fair_turn_margin:
            self._switch(now, best)  # a fair turn

    def _switch(self, now: float, key: str) -> None:
        self.focus = key
        self._focus_since = now
        self._focus_seen = now
        self._challenger = None
        self._goal = None  # a new person: no smoothing across the jump (the speed limit makes it smooth)

    # ---- nobody there: a glance around ------------------------------------------------------------------------
    def _idle(self, now: float) -> tuple[float, float] | None:
        cfg = self.cfg
        if self._nobody_since is None:
            self._nobody_since = now
            self._next_glance = now + cfg.idle_s
        if now < self._next_glance:
            return self._glance
        self._next_glance = now + cfg.glance_interval_s
        y = self._rng.uniform(-cfg.glance_y_m, cfg.glance_y_m)
        yaw = math.degrees(math.atan2(y, cfg.glance_x_m))
        pitch = -math.degrees(math.atan2(cfg.glance_z_m - cfg.eye_height_m, math.hypot(cfg.glance_x_m, y)))
        self._glance = (yaw, pitch)
        self._goal = None
        self._source = "glance"
        self._score = 0.0
        return self._glance

    # ---- moving there -----------------------------------------------------------------------------------------
    def _move(self, now: float, goal: tuple[float, float]) -> Target:
        cfg = self.cfg
        a = cfg.smoothing
        if self._goal is None:
            self._goal = goal
        else:
            self._goal = (self._goal[0] + a * (goal[0] - self._goal[0]), self._goal[1] + a * (goal[1] - self._goal[1]))
        gy = min(max(self._goal[0], self.yaw_limits[0]), self.yaw_limits[1])
        gp = min(max(self._goal[1], self.pitch_limits[0]), self.pitch_limits[1])
        dt = 1.0 / cfg.rate_hz if self._last is None else max(0.0, now - self._last)
        self._last = now
        limit = cfg.max_speed_deg_s * dt
        here = self.out or (0.0, 0.0)
        # a diagonal move keeps to the limit too: both axes scaled by the same factor
        dy, dp = gy - here[0], gp - here[1]
        length = math.hypot(dy, dp)
        k = 1.0 if length <= limit else limit / length
        self.out = (here[0] + k * dy, here[1] + k * dp)
        return Target(self._source, self.focus or "", self.out[0], self.out[1], self._score)
