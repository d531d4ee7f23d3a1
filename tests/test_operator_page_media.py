"""The operator page's camera and the robot's audio over WebRTC (issues 19 and 20), in Debian's Chromium with the
headset emulated by IWER, against the stand-in: the page negotiates through /vr_teleop/media/offer on its rosbridge
connection, shows the video on its panel with the frame's age from the telemetry's RTP mapping, and falls back to
the JPEG topic when WebRTC is refused, missing or fails later, saying so on the HUD."""

from __future__ import annotations

import asyncio
import shutil
import wave
from pathlib import Path

import numpy as np

import pytest

from support import RunningServer, wait_for
from test_operator_page import (SLOW, close_page, enter_vr, frames, hud, open_page, pixels_differ, screenshot,
                                set_head, settles, take_control)
from test_operator_page import iwer  # noqa: F401  (the fixture)

pytestmark = pytest.mark.timeout(300)

# Chromium offers only codecs the server cannot send (VP9, AV1): the server rejects the video section, for real
# (the offer's poses data channel and audio are answered: the connection stays up for them). Its receiver says it
# has no others, so the page's own codec order (webrtc.js codecOrder, issue 36) has no others to put first.
NO_COMMON_CODEC = """(() => {
  const caps = RTCRtpReceiver.getCapabilities.bind(RTCRtpReceiver);
  const only = (c) => /VP9|AV1/i.test(c.mimeType);
  RTCRtpReceiver.getCapabilities = (kind) => {
    const all = caps(kind);
    return kind === "video" && all ? {...all, codecs: all.codecs.filter(only)} : all;
  };
  const add = RTCPeerConnection.prototype.addTransceiver;
  RTCPeerConnection.prototype.addTransceiver = function (kind, init) {
    const t = add.call(this, kind, init);
    if (kind === "video") t.setCodecPreferences(caps("video").codecs.filter(only));
    return t;
  };
})();"""


# The Quest browser's answer for its H.264 WebRTC decoder (hardware: powerEfficient), in place of Chromium's own
# (Debian's decodes H.264 in software: powerEfficient false); every other question gets the browser's own answer.
QUEST_H264_DECODER = """(() => {
  const own = navigator.mediaCapabilities.decodingInfo.bind(navigator.mediaCapabilities);
  navigator.mediaCapabilities.decodingInfo = async (config) => {
    if (config?.type === "webrtc" && /^video\\/h264/i.test(config.video?.contentType ?? "")) {
      return {supported: true, smooth: true, powerEfficient: true};
    }
    return own(config);
  };
})();"""


@pytest.fixture(scope="module")
def media_server(module_servers) -> RunningServer:
    """The stand-in with its bystanders silent: the robot's audio holds only what the tests make it say."""
    return module_servers(backend="sim", bystander_interval=0)


def peers(server: RunningServer) -> int:
    return server.call(lambda: len(server.server.media.peers))


@pytest.fixture(scope="module")
def tone_browser(browser, tmp_path_factory: pytest.TempPathFactory):
    """A second Chromium from the same Playwright whose microphone is a steady 440 Hz tone (Chromium's fake capture
    device playing a WAV in a loop), the permission granted without a prompt."""
    path = tmp_path_factory.mktemp("tone") / "tone.wav"
    t = np.arange(48000) / 48000
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(48000)
        w.writeframes((np.sin(2 * np.pi * 440 * t) * 0.5 * 32767).astype("<i2").tobytes())
    b = browser.browser_type.launch(executable_path=shutil.which("chromium") or shutil.which("chromium-browser"),
                                    args=["--no-sandbox", "--enable-unsafe-swiftshader",
                                          "--use-fake-device-for-media-stream", "--use-fake-ui-for-media-stream",
                                          f"--use-file-for-fake-audio-capture={path}"])
    yield b
    b.close()


def left_trigger(page, value: float) -> None:
    page.evaluate(f"xrDevice.controllers.left.updateButtonValue('trigger', {value})")
    frames(page)


def voice_frames(server: RunningServer) -> int:
    """Operator voice frames the server decoded from the page's peer connection."""
    def count() -> int:
        return sum(p.voice.frames for p in server.server.media.peers.values() if p.voice is not None)
    return server.call(count)


def stopped(page, read, frames: int = 30) -> bool:
    """read() holds still while the page's panel shows `frames` more camera frames (a second of the server's steady
    video stream), not over a window of wall-clock time."""
    value = read()
    uploaded = page.evaluate("window.operator.camera.uploaded")
    page.wait_for_function(f"window.operator.camera.uploaded >= {uploaded + frames}", timeout=SLOW)
    return read() == value


def test_the_panel_shows_webrtc_video_that_follows_the_head(browser, iwer, media_server):  # noqa: F811
    standin = media_server.server.robot.standin
    page = open_page(browser, media_server, headset=iwer, camera="webrtc")
    try:
        enter_vr(page)
        page.wait_for_function("window.operator.camera.path === 'WebRTC' && window.operator.camera.uploaded >= 3",
                               timeout=SLOW)
        assert peers(media_server) == 1
        assert page.evaluate("window.operator.camera.jpeg") is None  # the JPEG topic was never asked for
        take_control(page)
        assert settles(standin, "HeadYaw", 0.0, 2.0)
        uploaded = page.evaluate("window.operator.camera.uploaded")
        page.wait_for_function(f"window.operator.camera.uploaded >= {uploaded + 3}", timeout=SLOW)
        before = page.evaluate("window.operator.readPixels()")
        screenshot(page, "operator_vr_webrtc.png")

        set_head(page, 30.0)
        assert settles(standin, "HeadYaw", 30.0, 2.0), standin.joint_positions()
        uploaded = page.evaluate("window.operator.camera.uploaded")
        page.wait_for_function(f"window.operator.camera.uploaded >= {uploaded + 3}", timeout=SLOW)
        after = page.evaluate("window.operator.readPixels()")
        assert pixels_differ(before, after) > 5, "the WebRTC panel did not change as the robot's head turned"
        screenshot(page, "operator_vr_webrtc_turned.png")

        # The frame's age, from its RTP timestamp and the telemetry's render times, on the HUD and in the figures.
        page.wait_for_function("/camera frame \\d+ ms old \\(WebRTC, (VP8|H\\.264)\\)/.test("
                               "(document.getElementById('hud-numbers')?.textContent ?? ''))", timeout=SLOW)
        page.wait_for_function("window.operator.camera.ages.length >= 10", timeout=SLOW)
        ages = page.evaluate("window.operator.camera.ages")
        # Rendered before shown (a clock synchronised to the server), and not older than the server keeps frames.
        assert all(-0.02 < a < 5.0 for a in ages), ages
        assert page.evaluate("window.operator.camera.clock.synced")
        assert page.errors == []
    finally:
        close_page(page)
    assert wait_for(lambda: peers(media_server) == 0, 30)  # the peer connection went with the page


def test_a_refused_offer_falls_back_to_the_jpeg_topic_and_says_so(browser, iwer, media_server):  # noqa: F811
    page = open_page(browser, media_server, headset=iwer, camera="webrtc", init_scripts=(NO_COMMON_CODEC,))
    try:
        page.wait_for_function("window.operator.camera.path === 'JPEG'", timeout=SLOW)
        page.wait_for_function("(document.getElementById('hud-message')?.textContent ?? '')"
                               ".startsWith('camera: WebRTC refused (no common codec')", timeout=SLOW)
        assert "showing the JPEG topic" in hud(page, "message")
        enter_vr(page)
        page.wait_for_function("window.operator.camera.uploaded >= 3", timeout=SLOW)  # JPEG frames on the panel
        page.wait_for_function("/camera frame \\d+ ms old \\(JPEG\\)/.test("
                               "(document.getElementById('hud-numbers')?.textContent ?? ''))", timeout=SLOW)
        # Issue 21: the peer connection stays for the poses channel (before, the whole offer was refused).
        assert peers(media_server) == 1
        page.wait_for_function("window.operator.poses.open", timeout=SLOW)
        assert page.errors == []
    finally:
        close_page(page)


def test_camera_jpeg_in_the_url_or_no_webrtc_means_the_jpeg_topic(browser, iwer, media_server):  # noqa: F811
    page = open_page(browser, media_server, camera="jpeg")
    try:
        page.wait_for_function("window.operator.camera.path === 'JPEG' && window.operator.camera.uploaded >= 2",
                               timeout=SLOW)
        frames(page, 10)
        assert peers(media_server) == 0  # never offered
    finally:
        close_page(page)
    page = open_page(browser, media_server, camera="webrtc", init_scripts=("delete window.RTCPeerConnection;",))
    try:
        page.wait_for_function("window.operator.camera.path === 'JPEG' && window.operator.camera.uploaded >= 2",
                               timeout=SLOW)
        assert "this browser has no WebRTC" in hud(page, "message")
        assert page.errors == []
    finally:
        close_page(page)


@pytest.mark.parametrize("decoder, option, expected", [
    ("quest", "", "H264"),   # the browser says its H.264 decoder is hardware: H.264 first
    ("own", "", "VP8"),      # Chromium's software H.264: VP8
    ("own", "h264", "H264"),  # the address forces H.264
], ids=["hardware-h264", "software-h264", "forced-h264"])
def test_the_page_asks_for_h264_where_it_decodes_it_in_hardware_and_says_which_codec(browser, media_server, decoder,
                                                                                     option, expected):
    """Issue 36: the codec the page asks for first is the one the server sends, Chromium decodes (frames shown,
    getStats' inbound codec) and the HUD names. Debian's Chromium has an H.264 decoder for WebRTC (FFmpeg's); were
    it built without one (no H.264 in RTCRtpReceiver.getCapabilities), H.264 cannot be had and the page must land on
    VP8 and say why: that is then what is checked."""
    page = open_page(browser, media_server, camera="webrtc" + (f"&codec={option}" if option else ""),
                     init_scripts=(QUEST_H264_DECODER,) if decoder == "quest" else ())
    try:
        has_h264 = page.evaluate("RTCRtpReceiver.getCapabilities('video').codecs"
                                 ".some((c) => c.mimeType.toLowerCase() === 'video/h264')")
        want = expected if has_h264 or option else "VP8"
        page.wait_for_function("window.operator.camera.path === 'WebRTC' && window.operator.camera.uploaded >= 3",
                               timeout=SLOW)
        camera = page.evaluate("({codec: window.operator.camera.codec, choice: window.operator.camera.codecChoice})")
        assert camera["codec"] == want, camera
        if not has_h264 and not option:
            assert camera["choice"]["why"] == "this browser's WebRTC has no H.264", camera
        owner = media_server.call(lambda: next(iter(media_server.server.media.peers)))
        assert media_server.call(lambda: media_server.server.media.peers[owner].video.codec) == want
        in_use = page.evaluate("""async () => {
          const stats = await window.operator.camera.pc.getStats();
          let codec = "";
          stats.forEach((s) => {
            if (s.type === "inbound-rtp" && s.kind === "video") codec = stats.get(s.codecId)?.mimeType ?? "";
          });
          return codec;
        }""")
        assert in_use.lower() == f"video/{want.lower()}", in_use  # what the browser decodes
        name = {"H264": "H.264", "VP8": "VP8"}[want]
        page.wait_for_function(f"(document.getElementById('hud-numbers')?.textContent ?? '')"
                               f".includes('(WebRTC, {name})')", timeout=SLOW)
        assert page.errors == []
    finally:
        close_page(page)
    assert wait_for(lambda: peers(media_server) == 0, 30)


def test_a_peer_connection_that_fails_later_falls_back_to_the_jpeg_topic(browser, iwer, media_server):  # noqa: F811
    page = open_page(browser, media_server, headset=iwer, camera="webrtc")
    try:
        page.wait_for_function("window.operator.camera.path === 'WebRTC' && window.operator.camera.uploaded >= 3",
                               timeout=SLOW)
        media = media_server.server.media
        owner = media_server.call(lambda: next(iter(media.peers)))
        # The server's teardown of a failed peer (ICE consent lost, DTLS failed), while the WebSocket stays up.
        asyncio.run_coroutine_threadsafe(media._close_peer(owner), media_server.loop).result(10)
        page.wait_for_function("window.operator.camera.path === 'JPEG'", timeout=60_000)
        page.wait_for_function("(document.getElementById('hud-message')?.textContent ?? '')"
                               ".startsWith('camera: the WebRTC connection')", timeout=SLOW)
        uploaded = page.evaluate("window.operator.camera.uploaded")
        page.wait_for_function(f"window.operator.camera.uploaded >= {uploaded + 3}", timeout=SLOW)
        assert page.evaluate("window.operator.ros.connected")
        assert page.errors == []
    finally:
        close_page(page)


def test_a_reconnected_page_negotiates_webrtc_again(servers, browser):
    """The server closes a connection's peer connection with it: after a dropped connection the page offers again
    on the new one, and does not fall back to JPEG for what was only the connection going."""
    first = servers(backend="sim", bystander_interval=0)
    port = first.port
    page = open_page(browser, first, camera="webrtc", ready="window.operator && window.operator.ros.connected")
    try:
        page.wait_for_function("window.operator.camera.path === 'WebRTC' && window.operator.camera.uploaded >= 3",
                               timeout=SLOW)
        first.stop()
        page.wait_for_function("(document.getElementById('hud-connection')?.textContent ?? '').includes('DISCONNECTED')",
                               timeout=SLOW)
        second = servers(port=port, backend="sim", bystander_interval=0)
        try:
            page.wait_for_function("(document.getElementById('hud-connection')?.textContent ?? '').startsWith('● connected')",
                                   timeout=SLOW)
            assert wait_for(lambda: peers(second) == 1, 30)
            received = page.evaluate("window.operator.camera.video.received")
            page.wait_for_function(f"window.operator.camera.video.received >= {received + 5}", timeout=SLOW)
            assert page.evaluate("window.operator.camera.path") == "WebRTC"
            assert page.evaluate("window.operator.camera.jpeg") is None
            assert page.errors == []
        finally:
            second.stop()
    finally:
        close_page(page)


def test_the_robots_audio_comes_over_webrtc_and_plays_once(browser, media_server):
    """Said through the speech menu: the audio track carries energy, and the AudioData topic's copy is not played
    as well."""
    page = open_page(browser, media_server, camera="webrtc", viewport={"width": 1000, "height": 640})
    try:
        page.wait_for_function("window.operator.camera.path === 'WebRTC' && window.operator.camera.audioViaWebRtc",
                               timeout=SLOW)
        page.keyboard.press("y")  # a user gesture: sound may play; Y opens the speech menu
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Speech'", timeout=SLOW)
        assert not page.evaluate("window.operator.camera.video.video.muted")
        energy = """async () => {
          const stats = await window.operator.camera.peerConnection.getStats();
          let e = 0;
          stats.forEach((s) => { if (s.type === 'inbound-rtp' && s.kind === 'audio') e = s.totalAudioEnergy || 0; });
          return e;
        }"""
        packets = energy.replace("totalAudioEnergy", "packetsReceived")
        assert wait_for(lambda: page.evaluate(packets) >= 50, 30)  # the robot's audio flows: a second of 20 ms packets
        quiet = page.evaluate(energy)
        page.keyboard.down("ArrowUp")
        page.keyboard.down("ArrowLeft")  # the diagonal item, Sentences
        page.keyboard.up("ArrowLeft")
        page.keyboard.up("ArrowUp")
        page.keyboard.press("Enter")
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Speech › Sentences'",
                               timeout=SLOW)
        page.keyboard.press("ArrowDown")
        page.keyboard.press("Enter")  # "Hello everyone, I am QT."
        assert wait_for(lambda: page.evaluate(energy) > quiet + 0.01, 30), (quiet, page.evaluate(energy))
        assert page.evaluate("window.operator.audio.topicMuted")
        assert page.evaluate("window.operator.audio.played") == 0  # not twice
        assert page.errors == []
    finally:
        close_page(page)


def test_the_left_trigger_sends_the_voice_over_webrtc_and_releasing_it_stops(tone_browser, iwer,  # noqa: F811
                                                                           media_server):
    """Push-to-talk on the peer connection the camera negotiated: the stand-in's mouth moves with the tone (the
    rosbridge road does not move it), the page publishes no PCM chunk, and releasing the trigger stops the
    track's packets and closes the mouth."""
    standin = media_server.server.robot.standin
    audio_dir = Path(media_server.settings.audio_dir)
    before = set(audio_dir.glob("*.wav")) if audio_dir.exists() else set()
    page = open_page(tone_browser, media_server, headset=iwer, camera="webrtc")
    try:
        enter_vr(page)
        page.wait_for_function("window.operator.camera.path === 'WebRTC' && window.operator.audio.path === 'WebRTC'",
                               timeout=SLOW)
        assert wait_for(lambda: peers(media_server) == 1, 30)
        assert voice_frames(media_server) == 0  # a place for the voice, nothing sent before push-to-talk
        left_trigger(page, 1.0)
        page.wait_for_function("(document.getElementById('hud-numbers')?.textContent ?? '')"
                               ".includes('TALKING (WebRTC)')", timeout=SLOW)
        assert wait_for(lambda: standin.voice_level > 0.5, 30), standin.voice_level
        assert wait_for(lambda: voice_frames(media_server) >= 50, 30)
        assert page.evaluate("window.operator.audio.sentChunks") == 0  # not over the rosbridge topic as well

        left_trigger(page, 0.0)
        page.wait_for_function("!(document.getElementById('hud-numbers')?.textContent ?? '').includes('TALKING')",
                               timeout=SLOW)
        assert wait_for(lambda: stopped(page, lambda: voice_frames(media_server)), 30), "the voice kept coming"
        assert wait_for(lambda: standin.voice_level == 0.0, 30)
        assert page.evaluate("window.operator.camera.path") == "WebRTC"  # the camera went on meanwhile

        left_trigger(page, 1.0)  # a second press: on the same peer connection again
        assert wait_for(lambda: standin.voice_level > 0.5, 30), standin.voice_level
        left_trigger(page, 0.0)
        assert wait_for(lambda: standin.voice_level == 0.0, 30)
        assert page.evaluate("window.operator.audio.sentChunks") == 0
        wavs = set(audio_dir.glob("*.wav")) - before  # logged as the rosbridge road's voice is
        assert wavs and max(p.stat().st_size for p in wavs) > 48000, wavs
        assert page.errors == []
    finally:
        close_page(page)


def test_without_a_microphone_push_to_talk_is_off_and_says_so(browser, media_server):
    """Chromium with no microphone allowed: the first press says why push-to-talk is off and the HUD keeps saying
    it; the camera stays on WebRTC."""
    page = open_page(browser, media_server, camera="webrtc")
    try:
        page.wait_for_function("window.operator.camera.path === 'WebRTC'", timeout=SLOW)
        page.keyboard.down("t")
        page.wait_for_function("window.operator.audio.micState === 'denied'", timeout=SLOW)
        page.keyboard.up("t")
        assert "push-to-talk is off" in hud(page, "message")
        page.wait_for_function("(document.getElementById('hud-numbers')?.textContent ?? '')"
                               ".includes('voice OFF (no microphone)')", timeout=SLOW)
        assert page.evaluate("window.operator.audio.sentChunks") == 0
        assert page.evaluate("window.operator.camera.path") == "WebRTC"
        assert page.errors == []
    finally:
        close_page(page)


def test_rtp_mapping_and_url_modes_under_node(tmp_path):
    """webrtc.js's pure parts, run by Node: RTP timestamps across the 32-bit wrap, the telemetry entry that is
    ours (RTP timestamps near the ones we receive), estimates between reports, and #camera=... parsing."""
    import json
    import subprocess
    from pathlib import Path

    module = Path(__file__).resolve().parent.parent / "vr_teleop_server" / "web" / "webrtc.js"
    script = tmp_path / "check.mjs"
    script.write_text(f"""
import {{rtpDelta, RenderTimes, cameraMode}} from {json.dumps(str(module))};
let onTelemetry = null;
const times = new RenderTimes({{subscribe: (topic, type, cb) => {{ onTelemetry = cb; }}}});
const out = {{}};
out.wrap = rtpDelta(5, 2 ** 32 - 5);
out.back = rtpDelta(2 ** 32 - 5, 5);
const entry = (rtp, t) => ({{rtp_clock_rate: 90000, rtp_timestamp: rtp, rtp_render_time: t,
                            frame_rtp_timestamps: [rtp - 3000, rtp], frame_render_times: [t - 1 / 30, t]}});
const known = [];
times.whenKnown(4294963996, (t) => known.push(t));  // before we saw any frame: waits
times.saw(4294967000);
onTelemetry({{clients: [entry(123456789, 50.0), entry(4294967296 - 300, 100.0)]}});  // theirs, ours
out.known = known;
out.lookup = times.lookup(4294966996);
out.theirs = times.lookup(123456789) ?? null;
out.estimate = times.estimate(2700);  // 3000 ticks after our newest (across the wrap): 1/30 s later
out.modes = [cameraMode("#token=abc&camera=jpeg"), cameraMode("#camera=webrtc"), cameraMode("")];
console.log(JSON.stringify(out));
""")
    result = subprocess.run(["node", str(script)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    assert out["wrap"] == 10 and out["back"] == -10
    assert out["known"] == [100.0 - 1 / 30] and out["lookup"] == 100.0
    assert out["theirs"] is None  # another peer's frames are not ours
    assert abs(out["estimate"] - (100.0 + 1 / 30)) < 1e-9
    assert out["modes"] == ["jpeg", "webrtc", "webrtc"]


def test_codec_choice_and_offer_order_under_node(tmp_path):
    """webrtc.js's codec choice (issue 36), run by Node with the browser's answers given: the address's codec=...
    first, then mediaCapabilities' powerEfficient, then the Quest browser's user agent; the codec order for
    setCodecPreferences, the offer text reordered for browsers without it, and the answer's codec read back."""
    import json
    import subprocess
    from pathlib import Path

    module = Path(__file__).resolve().parent.parent / "vr_teleop_server" / "web" / "webrtc.js"
    script = tmp_path / "codec.mjs"
    script.write_text(f"""
import {{chooseVideoCodec, codecOption, codecOrder, preferVideoCodec, firstVideoCodec}} from {json.dumps(str(module))};
const caps = {{codecs: [{{mimeType: "video/VP8"}}, {{mimeType: "video/rtx"}},
  {{mimeType: "video/H264", sdpFmtpLine: "level-asymmetry-allowed=1;packetization-mode=0;profile-level-id=42001f"}},
  {{mimeType: "video/H264", sdpFmtpLine: "level-asymmetry-allowed=1;packetization-mode=1;profile-level-id=4d001f"}},
  {{mimeType: "video/H264", sdpFmtpLine: "level-asymmetry-allowed=1;packetization-mode=1;profile-level-id=42e01f"}},
  {{mimeType: "video/AV1"}}]}};
const vp8Only = {{codecs: [{{mimeType: "video/VP8"}}]}};
const decoder = (powerEfficient) => ({{decodingInfo: async (c) => ({{supported: true, smooth: true,
  powerEfficient: powerEfficient && c.type === "webrtc" && /h264/.test(c.video.contentType)}})}});
const noWebrtcQueries = {{decodingInfo: async () => {{ throw new TypeError("type webrtc"); }}}};
const quest = "Mozilla/5.0 (X11; Linux x86_64; Quest 3) AppleWebKit/537.36 (KHTML, like Gecko) OculusBrowser/37.0 " +
  "SamsungBrowser/4.0 Chrome/128.0 VR Safari/537.36";
const none = {{codec: "", problem: ""}};
const pick = async (o) => (await chooseVideoCodec({{option: none, capabilities: caps, userAgent: "", ...o}})).codec;
const out = {{}};
out.hardware = await pick({{mediaCapabilities: decoder(true)}});
out.software = await pick({{mediaCapabilities: decoder(false)}});
out.questNoApi = await pick({{mediaCapabilities: undefined, userAgent: quest}});
out.questRefused = await pick({{mediaCapabilities: noWebrtcQueries, userAgent: quest}});
out.otherNoApi = await pick({{mediaCapabilities: undefined}});
out.noH264 = await pick({{mediaCapabilities: decoder(true), capabilities: vp8Only}});
out.forcedVp8 = await pick({{mediaCapabilities: decoder(true), option: codecOption("#token=x&codec=vp8")}});
out.forcedH264 = await pick({{mediaCapabilities: decoder(false), option: codecOption("", "?codec=H264")}});
out.options = [codecOption("#codec=av1"), codecOption("#camera=webrtc"), codecOption("#codec=h264", "?codec=vp8")];
out.order = codecOrder(caps.codecs, "H264").map((c) => c.mimeType + " " + (c.sdpFmtpLine ?? ""));
out.vp8Order = codecOrder(caps.codecs, "VP8").map((c) => c.mimeType);
const offer = ["v=0", "m=audio 9 UDP/TLS/RTP/SAVPF 111", "a=rtpmap:111 opus/48000/2",
  "m=video 9 UDP/TLS/RTP/SAVPF 96 97 102 103 45", "a=rtpmap:96 VP8/90000", "a=rtpmap:97 rtx/90000",
  "a=rtpmap:102 H264/90000", "a=rtpmap:103 rtx/90000", "a=rtpmap:45 AV1/90000", ""].join("\\r\\n");
const h264First = preferVideoCodec(offer, "H264");
out.mline = h264First.split("\\r\\n")[3];
out.same = preferVideoCodec(offer, "VP8") === offer && preferVideoCodec(offer, "") === offer;
out.first = [firstVideoCodec(offer), firstVideoCodec(h264First), firstVideoCodec("m=audio 9 RTP 111"),
             firstVideoCodec(offer.replace("m=video 9", "m=video 0"))];
console.log(JSON.stringify(out));
""")
    result = subprocess.run(["node", str(script)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    assert (out["hardware"], out["software"]) == ("H264", "VP8")
    assert (out["questNoApi"], out["questRefused"], out["otherNoApi"]) == ("H264", "H264", "VP8")
    assert out["noH264"] == "VP8"  # no H.264 in this browser's WebRTC, whatever its decoder says
    assert (out["forcedVp8"], out["forcedH264"]) == ("VP8", "H264")  # the address wins
    bad, unset, both = out["options"]
    assert bad["codec"] == "" and "codec=av1" in bad["problem"] and "h264 or vp8" in bad["problem"]
    assert unset == {"codec": "", "problem": ""} and both["codec"] == "H264"  # the hash before the query
    # H.264 first, the one the server sends (packetization-mode 1, constrained baseline) before the others
    assert out["order"][0] == "video/H264 level-asymmetry-allowed=1;packetization-mode=1;profile-level-id=42e01f"
    assert [o.split()[0] for o in out["order"]] == ["video/H264"] * 3 + ["video/VP8", "video/rtx", "video/AV1"]
    assert out["vp8Order"] == ["video/VP8", "video/rtx", "video/H264", "video/H264", "video/H264", "video/AV1"]
    assert out["mline"] == "m=video 9 UDP/TLS/RTP/SAVPF 102 96 97 103 45"
    assert out["same"]
    assert out["first"] == ["VP8", "H264", "", ""]


def test_a_stalled_pose_channel_hands_the_head_to_rosbridge_under_node(tmp_path):
    """pose_channel.js with a stand-in channel, run by Node: a frame's messages go out at its flush as ONE binary
    pose frame, which the server's decoder (client_protocol/pose_frame.py) reads back; while the channel is congested
    nothing goes and each topic keeps its newest; when it has taken no head pose for STALL_MS and still holds more
    than its budget, send() answers false for head poses (main.js then publishes them over rosbridge) but keeps the
    other streams; once it drains, the head goes back to the channel."""
    import base64
    import json
    import subprocess
    from pathlib import Path

    from client_protocol import pose_frame

    module = Path(__file__).resolve().parent.parent / "vr_teleop_server" / "web" / "operator" / "pose_channel.js"
    script = tmp_path / "check.mjs"
    script.write_text(f"""
import {{PoseChannel, STALL_MS, BUFFER_BUDGET}} from {json.dumps(str(module))};
let t = 0;
const sent = [];
const channel = {{readyState: "open", bufferedAmount: 0, bufferedAmountLowThreshold: 0, addEventListener() {{}},
                  send(frame) {{ sent.push(Buffer.from(frame).toString("base64"));
                                 this.bufferedAmount += frame.byteLength; }}}};
const pc = {{createDataChannel: () => channel}};
const poses = new PoseChannel({{now: () => t}});
poses.attach(pc);
const head = "/vr/head/pose", left = "/vr/left_controller/pose", right = "/vr/right_controller/pose";
const leftJoy = "/vr/left_controller/joy", rightJoy = "/vr/right_controller/joy";
const pose = (secs, x) => ({{header: {{stamp: {{secs, nsecs: 250000000}}, frame_id: "webxr"}},
                            pose: {{position: {{x, y: -0.2, z: 1.5}},
                                    orientation: {{x: 0, y: 0, z: 0.6, w: 0.8}}}}}});
const joy = (secs, buttons) => ({{header: {{stamp: {{secs, nsecs: 0}}, frame_id: "webxr"}},
                                 axes: [0.5, -0.25, 1, 0.125], buttons}});
const out = {{}};
out.frame = [poses.send(head, pose(1700000000, 0.1)), poses.send(left, pose(1700000000, 0.2)),
             poses.send(right, pose(1700000000, 0.3)), poses.send(leftJoy, joy(1700000000, [1, 0, 1, 0])),
             poses.send(rightJoy, joy(1700000000, [0, 1, 0, 1]))];
out.beforeFlush = sent.length;                           // nothing goes before the frame ends
poses.flush();                                           // the whole frame: one message
channel.bufferedAmount = BUFFER_BUDGET + 1;              // congested from here on: nothing more is taken
t += STALL_MS / 2;
out.congested = poses.send(head, pose(1700000001, 2));   // waits: not yet a stall
poses.flush();
t += STALL_MS;
out.stalled = poses.send(head, pose(1700000002, 3));     // no head taken for 1.5 x STALL_MS: rosbridge
out.stalledAgain = poses.send(head, pose(1700000003, 4));
out.others = [poses.send(left, pose(1700000003, 5)), poses.send(left, pose(1700000004, 6))];  // newest kept
poses.flush();
channel.bufferedAmount = 0;                              // it drains
poses.flush();                                           // what waited: the newest left, not the stale heads
out.drained = poses.send(head, pose(1700000005, 7));
poses.flush();
out.sent = sent;
out.stats = poses.stats();
console.log(JSON.stringify(out));
""")
    result = subprocess.run(["node", str(script)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    assert out["frame"] == [True] * 5 and out["beforeFlush"] == 0
    assert out["congested"] and out["others"] == [True, True] and out["drained"]
    assert not out["stalled"] and not out["stalledAgain"]
    frames_sent = [pose_frame.decode(base64.b64decode(b)) for b in out["sent"]]
    assert [[topic for topic, _ in f] for f in frames_sent] == [
        list(pose_frame.POSE_TOPICS) + list(pose_frame.JOY_TOPICS), ["/vr/left_controller/pose"], ["/vr/head/pose"]]
    first = dict(frames_sent[0])
    head_msg = first["/vr/head/pose"]
    assert head_msg["header"] == {"seq": 0, "stamp": {"secs": 1700000000, "nsecs": 250000000}, "frame_id": ""}
    position, orientation = head_msg["pose"]["position"], head_msg["pose"]["orientation"]
    assert position == pytest.approx({"x": 0.1, "y": -0.2, "z": 1.5}, abs=1e-6)  # float32
    assert orientation == pytest.approx({"x": 0.0, "y": 0.0, "z": 0.6, "w": 0.8}, abs=1e-6)
    assert first["/vr/right_controller/pose"]["pose"]["position"]["x"] == pytest.approx(0.3, abs=1e-6)
    assert first["/vr/left_controller/joy"]["axes"] == [0.5, -0.25, 1.0, 0.125]
    assert first["/vr/left_controller/joy"]["buttons"] == [1, 0, 1, 0]
    assert first["/vr/right_controller/joy"]["buttons"] == [0, 1, 0, 1]
    assert dict(frames_sent[1])["/vr/left_controller/pose"]["pose"]["position"]["x"] == pytest.approx(6.0)
    assert dict(frames_sent[2])["/vr/head/pose"]["pose"]["position"]["x"] == pytest.approx(7.0)
    assert out["stats"]["failovers"] == 2 and out["stats"]["replaced"] == 1 and out["stats"]["sent"] == 3


def _counts(server: RunningServer) -> tuple[int, int, int, int, int]:
    """(messages received on the holder's data channel, binary pose frames among them, refused there, publish
    frames the channel handed to the session, frames the holder's WebSocket carried: the session's frames_in
    counts the channel's handed frames too)."""
    def read() -> tuple[int, int, int, int, int]:
        app = server.server
        holder = app.control.holder
        session = next(s for s in app.sessions.values() if s.operator == holder)
        peer = app.media.peers.get(session.name)
        counts = peer.poses.counts if peer is not None and peer.poses is not None else None
        received, binary, refused, handed = ((counts.received, counts.pose_frames, counts.refused, counts.handed)
                                             if counts else (0, 0, 0, 0))
        return received, binary, refused, handed, session.counters["frames_in"] - handed
    return server.call(read)


def test_poses_take_the_data_channel_when_webrtc_is_up_and_rosbridge_when_not(browser, iwer, media_server):  # noqa: F811
    standin = media_server.server.robot.standin
    page = open_page(browser, media_server, headset=iwer, camera="webrtc")
    try:
        enter_vr(page)
        page.wait_for_function("window.operator.camera.path === 'WebRTC' && window.operator.poses.open",
                               timeout=SLOW)
        take_control(page)  # engaging takes poses over rosbridge: the channel carries the holder's only
        set_head(page, 25.0)
        assert settles(standin, "HeadYaw", 25.0, 2.0), standin.joint_positions()
        channel0, binary0, refused0, handed0, websocket0 = _counts(media_server)
        frames(page, 60)
        channel1, binary1, refused1, handed1, websocket1 = _counts(media_server)
        # One binary pose frame per XR frame (issue 30), each with the head and both controllers (and the Joy when
        # it changed or is due): nothing else on the channel, and the WebSocket carries a few calls at most.
        assert channel1 - channel0 == binary1 - binary0 >= 30, (channel0, channel1, binary0, binary1)
        assert handed1 - handed0 >= 3 * (binary1 - binary0), (handed0, handed1, binary0, binary1)
        assert websocket1 - websocket0 < (handed1 - handed0) / 10, (websocket0, websocket1, handed0, handed1)
        assert refused1 == refused0 == 0
        set_head(page, -20.0)  # and the robot follows what came over the channel
        assert settles(standin, "HeadYaw", -20.0, 2.0), standin.joint_positions()
        assert page.evaluate("window.operator.poses.sent") >= channel1
        assert page.evaluate("window.operator.poses.failovers") == 0
        # the telemetry the page reads says the same: its link's data channel counts the frames
        page.wait_for_function(f"(window.operator.state.link?.dc_received ?? 0) >= {channel1}", timeout=SLOW)
        assert page.errors == []
    finally:
        close_page(page)
    assert wait_for(lambda: peers(media_server) == 0, 30)
    assert wait_for(lambda: media_server.server.control.holder is None, 30)
    page = open_page(browser, media_server, headset=iwer, camera="jpeg")
    try:
        enter_vr(page)
        take_control(page)
        set_head(page, 15.0)
        assert settles(standin, "HeadYaw", 15.0, 2.0), standin.joint_positions()
        channel0, _, _, _, websocket0 = _counts(media_server)
        frames(page, 60)
        channel1, _, _, _, websocket1 = _counts(media_server)
        assert peers(media_server) == 0 and channel1 == channel0 == 0
        assert websocket1 - websocket0 >= 120, (websocket0, websocket1)  # the poses took rosbridge
        assert not page.evaluate("window.operator.poses.open")
        assert page.errors == []
    finally:
        close_page(page)
