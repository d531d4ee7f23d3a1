"""The server's interface as data: every topic and service a client uses, with its type, direction, rate and one
example frame. It is exported with the JSON Schemas (schemas/interface.json) for the Unity team, and tests check
that each example fits its type and that a running server offers exactly these names with these types.

Directions are from the client's side: "publish" (client -> server), "subscribe" (server -> client), "call"
(a service the server provides).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Literal

from . import names

UNITY_HEAD_POSE = {
    "header": {"seq": 0, "stamp": {"secs": 1700000000, "nsecs": 0}, "frame_id": "unity_left_handed"},
    "pose": {"position": {"x": 0.0, "y": 1.62, "z": 0.0},
             "orientation": {"x": 0.0, "y": -0.2588, "z": 0.0, "w": 0.9659}},  # looking 30 degrees left
}


def _hand(x: float) -> dict[str, Any]:
    return {"header": {"seq": 0, "stamp": {"secs": 1700000000, "nsecs": 0}, "frame_id": "unity_left_handed"},
            "pose": {"position": {"x": x, "y": 1.35, "z": 0.45},
                     "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}


JOY_DOC = ("Oculus Touch, fixed layout. axes: [thumbstick x (-1 left..1 right), thumbstick y (-1 down..1 up), index "
           "trigger (0..1), grip (0..1)]; buttons: [A or X, B or Y, thumbstick click, menu] as 0/1. The grip is the "
           "arm's dead-man: pressed above 0.6, released below 0.4. Both thumbsticks clicked together is a soft "
           "e-stop. Send at least on every change; 30 Hz or more is usual.")
POSE_DOC = ("geometry_msgs/PoseStamped at the headset's rate (about 90 Hz). header.frame_id 'unity_left_handed' means Unity's "
            "axes (left-handed: x right, y up, z forward, metres); any other frame id means a right-handed ROS "
            "frame (x forward, y left, z up). NaN, infinity and non-unit quaternions are refused with a status "
            "error. While another client holds control, poses are refused with a status error.")


@dataclass(frozen=True)
class Endpoint:
    name: str
    type: str
    direction: Literal["publish", "subscribe", "call"]
    doc: str
    rate: str = ""
    example: dict[str, Any] = field(default_factory=dict)  # a message (topics) or call arguments (services)

    def example_frame(self) -> dict[str, Any]:
        """The rosbridge frame a client sends (publish, call_service) or receives (publish)."""
        if self.direction == "call":
            return {"op": "call_service", "service": self.name, "args": self.example}
        return {"op": "publish", "topic": self.name, "msg": self.example}


def _stamp() -> dict[str, Any]:
    return {"seq": 0, "stamp": {"secs": 1700000000, "nsecs": 0}, "frame_id": ""}


ENDPOINTS: tuple[Endpoint, ...] = (
    # ---- explicit control: the headset's streams ----
    Endpoint(names.HEAD_POSE_TOPIC, "geometry_msgs/PoseStamped", "publish", "The headset's pose. " + POSE_DOC, "90 Hz",
             UNITY_HEAD_POSE),
    Endpoint(names.CONTROLLER_POSE_TOPICS["left"], "geometry_msgs/PoseStamped", "publish",
             "The left Touch controller's pose. " + POSE_DOC, "90 Hz", _hand(-0.2)),
    Endpoint(names.CONTROLLER_POSE_TOPICS["right"], "geometry_msgs/PoseStamped", "publish",
             "The right Touch controller's pose. " + POSE_DOC, "90 Hz", _hand(0.2)),
    Endpoint(names.JOY_TOPICS["left"], "sensor_msgs/Joy", "publish", JOY_DOC, "on change, or 30+ Hz",
             {"header": _stamp(), "axes": [0.0, 0.0, 0.0, 1.0], "buttons": [0, 0, 0, 0]}),
    Endpoint(names.JOY_TOPICS["right"], "sensor_msgs/Joy", "publish", JOY_DOC, "on change, or 30+ Hz",
             {"header": _stamp(), "axes": [0.1, -0.3, 0.0, 0.85], "buttons": [1, 0, 0, 0]}),
    # ---- explicit control: the server's services and telemetry ----
    Endpoint(names.ENGAGE_SERVICE, "std_srvs/SetBool", "call",
             "data true: take control (needs a fresh head pose from the caller; the current head orientation "
             "becomes the robot's head zero). Engaging again while this operator already holds control changes "
             "nothing (success, and the message says control is already held); to make the current head "
             "orientation straight ahead, call " + names.RECENTER_SERVICE + ". data false: release it; the robot "
             "keeps its pose. Refused while another client holds control.", example={"data": True}),
    Endpoint(names.RECENTER_SERVICE, "std_srvs/Trigger", "call",
             "Re-center while holding control: the operator's current head orientation becomes straight ahead "
             "(the robot's head eases back to its centre as teleop resumes from there). Only the operator holding "
             "control may call it; refused (success false, the reason in message) otherwise or without a fresh "
             "head pose.", example={}),
    Endpoint(names.CALIBRATE_SERVICE, "std_srvs/Trigger", "call",
             "Measure the operator's shoulders and arm length from a T-pose (arms straight out to the sides), "
             "holding the headset and both controllers tracked. The reply's message holds the measurements as "
             "JSON."),
    Endpoint(names.HEAD_SERVICE, "std_srvs/SetBool", "call",
             "Whether the robot's head follows the operator's head (true by default).", example={"data": False}),
    Endpoint(names.ARMS_SERVICE, "std_srvs/SetBool", "call",
             "Whether the robot's arms may follow the controllers (true by default; each arm still needs its "
             "grip).", example={"data": True}),
    Endpoint(names.ESTOP_SERVICE, "std_srvs/Trigger", "call",
             "Emergency stop: the robot holds where it is and control is released. Any operator or supervisor "
             "may call it, holding control or not (spectators may not); engaging again resumes."),
    Endpoint(names.TELEOP_STATE_TOPIC, "vr_teleop_msgs/TeleopState", "subscribe",
             "Explicit control as the server sees it (see the type's comments for the states).",
             "30 Hz and on every change",
             {"header": _stamp(), "engaged": True, "state": "active", "holder": "client_3_127.0.0.1:50312",
              "head_following": True, "left_arm_following": False, "right_arm_following": True,
              "clamped": ["HeadYaw"], "velocity_limited": [], "pose_age": 0.004, "left_pose_age": 0.006,
              "right_pose_age": 0.005, "robot_connected": True}),
    Endpoint(names.EVENT_TOPIC, "vr_teleop_msgs/Event", "subscribe",
             "Server events: engage, release, calibrate, head_on/off, arms_on/off, estop, watchdog_*, robot_lost, "
             "robot_back, menu selections, gesture recording, motivation limits, the backend's news; every kind "
             "and its detail's fields are listed under Events below.",
             "on event",
             {"header": _stamp(), "source": "teleop", "kind": "watchdog_stalled", "level": "warning",
              "detail": "{\"holder\": \"client_3_127.0.0.1:50312\", \"pose_age_s\": 0.412, "
                        "\"pose_made_age_s\": 0.431, \"threshold_s\": 0.25}"}),
    Endpoint(names.CLAMP_TOPIC, "vr_teleop_msgs/Clamp", "subscribe",
             "A joint command that did not apply as sent: clamped to a limit, or ignored (motor not on).",
             "on clamp",
             {"header": _stamp(), "source": names.HEAD_COMMAND_TOPIC, "joints": ["HeadYaw"],
              "requested": [80.0], "applied": [60.0], "ignored": []}),
    # ---- implicit control: menus, speech, audio, status, motivation ----
    Endpoint(names.MENUS_TOPIC, "vr_teleop_msgs/Menus", "subscribe",
             "Every radial menu tree, flattened (items name their parent), latched: draw the menus from it. "
             "Published again when the gesture list changes.", "latched, on change",
             {"header": _stamp(), "menus": [{"id": "status", "label": "Status", "controller": "left", "button": "X",
                                             "icon": "info"}],
              "items": [{"id": "status.hardware", "menu": "status", "parent": "status", "label": "Hardware",
                         "slot": "left", "position": 0, "icon": "cpu", "command": "show_status",
                         "args": "{\"which\": \"hardware\"}"}]}),
    Endpoint(names.MENU_SELECT_SERVICE, "vr_teleop_msgs/MenuSelect", "call",
             "Run a menu item by id, as the selecting client. args (a JSON object, may be empty) is merged over "
             "the item's own. The reply says what happened; unknown ids and failed commands are errors.",
             example={"id": "speech.sentences.well_done", "args": ""}),
    Endpoint(names.MENU_SELECTION_TOPIC, "std_msgs/String", "publish",
             "The same as /vr_teleop/menu/select by item id, without a reply (errors come as status messages).",
             "on selection", {"data": "emotion.happy"}),
    Endpoint(names.ROBOT_AUDIO_TOPIC, "audio_common_msgs/AudioData", "subscribe",
             "What the robot says, as raw PCM chunks of 100 ms, sent in real time (300 ms ahead). Format on "
             "/vr_teleop/audio/robot/info.", "10 Hz while speaking", {"data": "AAABAAIA"}),
    Endpoint(names.ROBOT_AUDIO_INFO_TOPIC, "audio_common_msgs/AudioInfo", "subscribe",
             "The robot audio's format (latched).", "latched",
             {"channels": 1, "sample_rate": 22050, "sample_format": "S16LE", "bitrate": 352800,
              "coding_format": "pcm"}),
    Endpoint(names.OPERATOR_AUDIO_TOPIC, "audio_common_msgs/AudioData", "publish",
             "The operator's voice for the robot's speaker: raw PCM S16LE chunks, mono 16 kHz unless "
             "/vr_teleop/audio/operator/info says otherwise. Logged as one WAV per client (serve --audio-dir).",
             "e.g. 10 Hz", {"data": "AAABAAIA"}),
    Endpoint(names.OPERATOR_AUDIO_INFO_TOPIC, "audio_common_msgs/AudioInfo", "publish",
             "The format of the operator's chunks (S16LE, 1 or 2 channels), before sending them.", "once",
             {"channels": 1, "sample_rate": 48000, "sample_format": "S16LE", "bitrate": 768000,
              "coding_format": "pcm"}),
    Endpoint(names.SPEECH_CONFIG_SERVICE, "qt_robot_interface/speech_config", "call",
             "Voice language (espeak-ng: en, en-gb, fr...), pitch (1..100, 50 normal) and speed (percent of "
             "normal); 0 or empty keeps the current.", example={"language": "en-gb", "pitch": 50, "speed": 90}),
    Endpoint(names.GESTURE_RECORD_SERVICE, "qt_gesture_controller/gesture_record", "call",
             "Start recording the parts' joints while the operator moves the robot (idleParts is ignored: the "
             "parts stay powered for explicit control). wait: seconds before starting; timeout: seconds at most "
             "(0: until /qt_robot/gesture/stop or save).",
             example={"parts": ["right_arm"], "idleParts": False, "wait": 0, "timeout": 0}),
    Endpoint(names.GESTURE_SAVE_SERVICE, "qt_gesture_controller/gesture_save", "call",
             "Save the recording (stopping it) as a LuxAI gesture file named name in the server's gesture "
             "directory; path must be empty.", example={"name": "my_wave", "path": ""}),
    Endpoint(names.HARDWARE_STATUS_TOPIC, "vr_teleop_msgs/HardwareStatus", "subscribe",
             "The server machine's CPU, memory and temperature (the robot's own: robot_hardware).", "2 Hz",
             {"header": _stamp(), "cpu_percent": 23.5, "memory_percent": 41.0, "memory_used_mb": 3300.0,
              "has_temperature": True, "temperature_c": 52.0, "load_1min": 0.8}),
    Endpoint(names.ROBOT_HARDWARE_STATUS_TOPIC, "vr_teleop_msgs/RobotHardwareStatus", "subscribe",
             "The robot's own hardware as its backend reports it: the hottest motor, the lowest motor voltage, "
             "faults, and the robot's battery and computer where its interface gives them; each figure it cannot "
             "give is named in missing, with why.", "2 Hz",
             {"header": _stamp(), "backend": "ros", "source": "measured", "connected": True, "motors": 8,
              "has_motor_temperature": True, "hottest_motor": "RightShoulderPitch", "motor_temperature_c": 41.0,
              "has_motor_voltage": True, "motor_voltage_min_v": 11.9, "motor_faults": 0, "has_battery": False,
              "battery_percent": 0.0, "has_cpu": False, "cpu_percent": 0.0, "has_memory": False,
              "memory_percent": 0.0, "has_temperature": False, "temperature_c": 0.0,
              "missing": ["battery", "cpu", "memory", "temperature"],
              "missing_reason": ["interface", "interface", "interface", "interface"]}),
    Endpoint(names.MOTORS_STATUS_TOPIC, "vr_teleop_msgs/MotorsStatus", "subscribe",
             "Each motor once: position, position within its range (0..1), temperature, voltage, mode.", "2 Hz",
             {"header": _stamp(), "name": ["HeadYaw"], "position": [30.0], "position_normalized": [0.75],
              "temperature": [36.5], "voltage": [12.1], "mode": ["on"]}),
    Endpoint(names.DIALOG_STATUS_TOPIC, "vr_teleop_msgs/DialogState", "subscribe",
             "The dialog system's newest state.", "2 Hz and on change",
             {"header": _stamp(), "question": "What colour is the sky?", "mode": "quiz", "answer": "blue",
              "candidates": ["blue", "green"], "optionals": [], "chosen": "blue"}),
    Endpoint(names.DIALOG_UPDATE_TOPIC, "vr_teleop_msgs/DialogState", "publish",
             "A dialog system reports its state here; the status menu shows it.", "on change",
             {"header": _stamp(), "question": "Shall we sing?", "mode": "yes_no", "answer": "", "candidates":
              ["yes", "no"], "optionals": [], "chosen": ""}),
    Endpoint(names.MOTIVATION_STATUS_TOPIC, "vr_teleop_msgs/Motivation", "subscribe",
             "The motivation variables with their limits and levels.", "2 Hz and on change",
             {"header": _stamp(), "name": ["frustration"], "value": [82.0], "min": [0.0], "max": [90.0],
              "has_low": [False], "low": [0.0], "has_high": [True], "high": [80.0], "level": ["high"]}),
    Endpoint(names.MOTIVATION_INCREMENT_SERVICE, "vr_teleop_msgs/MotivationChange", "call",
             "Add value to a variable (clamped to its min..max); the reply holds the new value.",
             example={"name": "curiosity", "value": 5.0}),
    Endpoint(names.MOTIVATION_SET_SERVICE, "vr_teleop_msgs/MotivationChange", "call",
             "Set a variable (clamped to its min..max).", example={"name": "pain", "value": 2.0}),
    Endpoint(names.MOTIVATION_RESET_SERVICE, "vr_teleop_msgs/MotivationChange", "call",
             "Back to the initial value; an empty name resets every variable.", example={"name": "", "value": 0.0}),
    # ---- who am I; the robot avatar (Unity/ROS#) ----
    Endpoint(names.WHOAMI_SERVICE, "vr_teleop_msgs/WhoAmI", "call",
             "Who the server takes this connection to be: its name, role, operator key (shared by every connection "
             "of one operator; compare it with teleop_state's holder) and whether that operator holds control. "
             "Before any token (when the server has tokens): success false, message saying to log in.", "", {}),
    Endpoint(names.URDF_JOINT_STATES_TOPIC, "sensor_msgs/JointState", "subscribe",
             "Joint positions in radians under the URDF's joint names (robot_description), for ROS#'s "
             "JointStatePatcher; LuxAI's degrees stay on " + names.JOINT_STATE_TOPIC + ".", "30 Hz",
             {"header": _stamp(), "name": ["HeadYaw"], "position": [0.0], "velocity": [0.0], "effort": [0.0]}),
    Endpoint(names.FILE_SERVER_SERVICE, "file_server/GetBinaryFile", "call",
             "A package:// resource the robot_description parameter (rosapi get_param) names, as base64 bytes. A "
             "name outside the shipped packages gets an empty value (and a status warning).", "",
             {"name": "package://qtrobot_description/meshes/head.stl"}),
    # ---- the dashboard's own needs ----
    Endpoint(names.DESCRIPTION_TOPIC, "std_msgs/String", "subscribe",
             "The robot's joints as JSON: {robot, joints: [{name, part, lower, upper, home, max_velocity}]}, "
             "latched, so that clients draw gauges without hard-coding limits.", "latched",
             {"data": "{\"robot\": \"QTrobot\", \"joints\": [{\"name\": \"HeadYaw\", \"part\": \"head\", "
                      "\"lower\": -60.0, \"upper\": 60.0, \"home\": 0.0, \"max_velocity\": 60.0}]}"}),
    Endpoint(names.STUDY_LABELS_TOPIC, "vr_teleop_msgs/Event", "publish",
             "The experimenter's labels (source experimenter; kind human_action_start, human_action_stop or "
             "intervention; detail JSON {action, wall_time}); recorded with the session.", "on label",
             {"header": _stamp(), "source": "experimenter", "kind": "human_action_start", "level": "info",
              "detail": "{\"action\": \"hand_over_cup\", \"wall_time\": 1700000000.0}"}),
    Endpoint(names.FACES_TOPIC, "vr_teleop_msgs/Faces", "subscribe",
             "Bystanders' faces found in the head camera's frames (CenterFace, a CNN, through OpenCV's DNN), boxes "
             "in the frame's pixels with a confidence 0..1; frame_seq is the camera frame's header.seq. Searched "
             "only while someone subscribes.",
             "up to 5 Hz",
             {"header": {"seq": 42, "stamp": {"secs": 1700000000, "nsecs": 0},
                         "frame_id": "camera_color_optical_frame"},
              "frame_seq": 42, "image_width": 640, "image_height": 480, "detector":
              "centerface:480+320", "faces": [{"x": 301, "y": 170, "width": 40,
                                               "height": 46, "confidence": 0.62}]}),
    # ---- media: WebRTC video and voice beside the rosbridge stream (vr_teleop_server/media) ----
    Endpoint(names.MEDIA_OFFER_SERVICE, "vr_teleop_msgs/MediaOffer", "call",
             "WebRTC signalling over this rosbridge connection: send your RTCPeerConnection's offer (type 'offer', "
             "all candidates gathered), get the server's answer. Offer video recvonly for the head camera (VP8 or "
             "H264, --camera-size at --camera-fps), audio sendrecv for the robot's audio out (Opus: its speech and "
             "what its microphone hears) and your microphone in (Opus: played on the robot and logged, for an "
             "operator or supervisor). One peer connection per rosbridge connection, closed with it. Same access "
             "as the camera topic. Refusals: success false and the reason in message (malformed SDP, no common "
             "codec, no camera access, a second offer on this connection). A data channel labelled 'poses' "
             "(ordered false, maxRetransmits 0) carries the holder's /vr/* pose and Joy publish frames (README, "
             "Media), or binary messages each holding one XR frame's poses and Joy (client_protocol/pose_frame.py: "
             "fixed layout, versioned, little-endian); with one in the offer, a media section without a common codec is answered rejected (port 0, "
             "success true, the reason in message) instead of refusing the offer.",
             example={"sdp": "v=0\r\no=- 1 1 IN IP4 0.0.0.0\r\ns=-\r\nt=0 0\r\n"
                             "m=video 9 UDP/TLS/RTP/SAVPF 96\r\na=rtpmap:96 VP8/90000\r\na=recvonly\r\n",
                      "type": "offer"}),
    Endpoint(names.MEDIA_ICE_SERVERS_SERVICE, "vr_teleop_msgs/IceServers", "call",
             "The ICE servers for your RTCPeerConnection: call it before building each peer connection and pass "
             "ice_servers (as iceServers: urls, username, credential) to its configuration. With TURN (serve "
             "--turn-url, --turn-secret) each TURN entry carries fresh time-limited credentials for this "
             "connection's operator (coturn's use-auth-secret: username EXPIRY:OPERATOR_KEY, credential base64 "
             "HMAC-SHA1), valid until expires; the server's own peer uses the same servers. Without any, the list "
             "is empty (host candidates: enough on a LAN). Same access as the offer: a client that may not see "
             "the camera gets success false and the reason in message. Credentials are left out of recordings and "
             "logs.", example={}),
    Endpoint(names.CLOCK_SERVICE, "vr_teleop_msgs/Clock", "call",
             "NTP-style clock exchange: offset = ((server_receive - client_send) + (server_send - client_receive))"
             " / 2 puts the server's stamps (camera headers, rtp_render_time) on the client's clock.",
             example={"client_send": 1700000000.25}),
    Endpoint(names.TELEMETRY_TOPIC, "vr_teleop_msgs/Telemetry", "subscribe",
             "Every client's link: WebSocket round trip, pose rate and age, camera frames sent and dropped and "
             "their age at send, and for a peer connection its RTT, jitter, loss, bitrate, frames sent and each "
             "video frame's render time by RTP timestamp, the poses data channel's counts, and the link's quality for "
             "teleoperation with the reasons (see the type's comments).", "2 Hz",
             {"header": _stamp(), "clients": [{
                 "client": "/rosbridge_websocket/client_3", "role": "operator", "ws_rtt": 0.0021,
                 "pose_rate": 90.0, "pose_age": 0.011, "camera_frames_sent": 912, "camera_frames_dropped": 3,
                 "camera_frame_age": 0.019, "webrtc": True, "video_codec": "VP8", "rtc_state": "connected",
                 "rtc_rtt": 0.004, "rtc_jitter": 0.002, "rtc_packets_lost": 0, "rtc_fraction_lost": 0.0,
                 "rtc_bitrate": 840000.0, "rtc_target_bitrate": 900000.0, "rtc_frames_sent": 905,
                 "rtp_timestamp": 1772474006, "rtp_render_time": 1700000000.27, "rtp_clock_rate": 90000,
                 "frame_rtp_timestamps": [1772471006, 1772474006],
                 "frame_render_times": [1700000000.236, 1700000000.27], "operator_voice_level": 0.42,
                 "pose_jitter": 0.004, "watchdog_threshold": 0.2, "watchdog_holds": 0, "link_quality": "good",
                 "link_warning": "", "dc_received": 8100, "dc_refused": 0, "dc_stale_dropped": 12, "dc_last_refusal": ""}]}),
    # ---- supervised autonomy (docs/guides/autonomy.md) ----
    Endpoint(names.AUTONOMY_LEVEL_SERVICE, "vr_teleop_msgs/SetAutonomy", "call",
             "Set the autonomy level, live: teleoperated (nothing moves unless someone moves it), supervised (the "
             "robot looks at who speaks and proposes actions the teacher decides; an undecided one is done at its "
             "time-out), autonomous (it does what it proposes; the teacher still overrides everything). Operators "
             "and supervisors; an unknown level is refused (success false, the reason in message). Also lifts an "
             "emergency stop's hold on autonomy.", example={"level": "supervised"}),
    Endpoint(names.AUTONOMY_STATE_TOPIC, "vr_teleop_msgs/AutonomyState", "subscribe",
             "Autonomy as the server sees it: the level, the attention target, the pending proposals, what runs "
             "(attention, glance, proposal:ID) and each part's owner (operator, trial, gesture, autonomy, estop, "
             "none).", "latched, on change",
             {"header": _stamp(), "level": "supervised",
              "attention": {"header": _stamp(), "source": "both", "id": "child_left", "who": "child_left",
                            "yaw": 21.5, "pitch": 2.0, "has_face": True, "face": {"x": 180, "y": 200, "width": 40,
                                                                                 "height": 40, "confidence": 3.1},
                            "frame_seq": 4211, "score": 0.78},
              "pending": [], "running": ["attention"],
              "owners": [{"part": "head", "owner": "autonomy"}, {"part": "right_arm", "owner": "none"},
                         {"part": "left_arm", "owner": "none"}]}),
    Endpoint(names.AUTONOMY_ATTENTION_TOPIC, "vr_teleop_msgs/AttentionTarget", "subscribe",
             "Where the robot's attention is: a face, a voice or both (a speaking face), a glance around when "
             "nobody is there, or empty (teleoperated, or the head is someone else's). yaw/pitch in the base "
             "frame, degrees (yaw + left, pitch + down); a face's box with the camera frame it was found in "
             "(frame_seq).", "on change (a face's box: each detection) and 1 Hz, latched",
             {"header": _stamp(), "source": "face", "id": "face-3", "who": "Mia", "yaw": -27.3, "pitch": 4.0,
              "has_face": True, "face": {"x": 410, "y": 190, "width": 38, "height": 38, "confidence": 0.8},
              "frame_seq": 4211, "score": 0.55}),
    Endpoint(names.PEOPLE_RENAME_SERVICE, "vr_teleop_msgs/RenamePerson", "call",
             "Name a tracked person: every view (the dashboard, the operator's HUD and camera panel, the recording) "
             "shows the name for that track id from then on. The stand-in's pupils are tracked by their names "
             "(child_left...), a real robot's faces as face-1, face-2...; an empty name gives the id back. "
             "Operators and supervisors; an unknown id or a bad name is refused (success false, the reason in "
             "message).", example={"id": "face-3", "name": "Mia"}),
    Endpoint(names.AUTONOMY_PROPOSALS_TOPIC, "vr_teleop_msgs/Proposal", "subscribe",
             "An action the robot proposes (a menu item id), why, how sure, and what its time-out does. Decide it "
             "with " + names.AUTONOMY_DECIDE_SERVICE + "; its end comes on " + names.AUTONOMY_OUTCOMES_TOPIC + ".",
             "on proposal",
             {"header": _stamp(), "id": "p-3", "action": "speech.sentences.well_done", "label": "Well done!",
              "reason": "a pupil has stopped after speaking a while", "confidence": 0.7, "timeout": 6.0,
              "on_timeout": "execute", "situation": "speech_ended", "left": 6.0}),
    Endpoint(names.AUTONOMY_DECIDE_SERVICE, "vr_teleop_msgs/DecideProposal", "call",
             "Decide a pending proposal: accept (done now), reject (not now), forbid (never in this situation: "
             "the robot learns it). Operators and supervisors. An unknown or ended id, or another decision, is "
             "refused (success false, the reason in message).", example={"id": "p-3", "decision": "accept"}),
    Endpoint(names.AUTONOMY_OUTCOMES_TOPIC, "vr_teleop_msgs/ProposalOutcome", "subscribe",
             "Every proposal's end (accepted, rejected, forbidden, timed_out_executed, superseded, dropped), and "
             "each action the teacher took herself from a menu (teacher_initiated), with who decided and how "
             "long it took.", "on outcome",
             {"header": _stamp(), "id": "p-3", "action": "speech.sentences.well_done", "outcome": "accepted",
              "initiator": "robot", "decided_by": "op-1a2b3c4d5e6f", "seconds": 1.42,
              "situation": "speech_ended"}),
    # ---- the stand-in's simulated pupils (backend sim only) ----
    Endpoint(names.SIM_BYSTANDERS_TOPIC, "vr_teleop_msgs/Bystanders", "subscribe",
             "Simulation only: the stand-in's pupils, their places in the robot's base frame, where they look and "
             "whether they speak.", "latched, on change",
             {"header": _stamp(), "bystanders": [{"name": "child_left", "position": {"x": 1.65, "y": 0.65,
                                                                                      "z": 0.445},
                                                  "yaw": 21.5, "looking": "robot", "speaking": False}]}),
    Endpoint(names.SIM_BYSTANDERS_SPEAK_SERVICE, "vr_teleop_msgs/BystanderSpeak", "call",
             "Simulation only: a pupil says text (espeak-ng, into the robot's microphone: the operator hears it) "
             "while voice activity and its direction are reported as a microphone array would. Answers once the "
             "pupil has begun; refused for an unknown pupil, empty text, or a pupil already speaking.",
             example={"who": "child_left", "text": "I know the answer!"}),
    Endpoint(names.SIM_BYSTANDERS_LOOK_SERVICE, "vr_teleop_msgs/BystanderLook", "call",
             "Simulation only: a pupil looks at the robot or away.", example={"who": "child_right", "at": "away"}),
    # ---- LuxAI's QTrobot API (the stand-in serves it; the ros backend forwards it) ----
    Endpoint(names.HEAD_COMMAND_TOPIC, "std_msgs/Float64MultiArray", "publish",
             "[HeadYaw, HeadPitch] in degrees; clamped to limits (reported on /vr_teleop/clamps). Explicit control "
             "publishes here too, so subscribing shows its commands.", "as needed", {"data": [30.0, -5.0]}),
    Endpoint(names.LEFT_ARM_COMMAND_TOPIC, "std_msgs/Float64MultiArray", "publish",
             "[LeftShoulderPitch, LeftShoulderRoll, LeftElbowRoll] in degrees.", "as needed",
             {"data": [90.0, -60.0, -30.0]}),
    Endpoint(names.RIGHT_ARM_COMMAND_TOPIC, "std_msgs/Float64MultiArray", "publish",
             "[RightShoulderPitch, RightShoulderRoll, RightElbowRoll] in degrees.", "as needed",
             {"data": [-90.0, -60.0, -30.0]}),
    Endpoint(names.JOINT_STATE_TOPIC, "sensor_msgs/JointState", "subscribe",
             "All joints, alphabetical, positions in degrees.", "30 Hz",
             {"header": _stamp(), "name": ["HeadPitch", "HeadYaw"], "position": [0.0, 12.5], "velocity": [0.0, 3.1],
              "effort": [0.0, 0.0]}),
    Endpoint(names.CAMERA_TOPIC, "sensor_msgs/CompressedImage", "subscribe",
             "The head camera as JPEG, rendered only while someone subscribes.", "30 Hz (serve --camera-fps)",
             {"header": {"seq": 1, "stamp": {"secs": 1700000000, "nsecs": 0},
                         "frame_id": names.CAMERA_FRAME_ID}, "format": "jpeg", "data": "/9j/4AAQSkZJRg=="}),
    Endpoint(names.CAPTURE_POSE_TOPIC, "vr_teleop_msgs/CapturePose", "subscribe",
             "Each camera frame's head pose when it was taken (HeadYaw, HeadPitch in degrees), published just before "
             "the frame on " + names.CAMERA_TOPIC + " while someone watches it; its header is the frame's own: "
             "match the two by header stamp. Show a frame where the robot looked when it took it (the operator "
             "page places its camera panel so). A client that ignores it loses nothing. WebRTC frames get theirs on "
             "the '" + names.CAPTURE_POSES_CHANNEL + "' data channel, keyed by RTP timestamp.",
             "with each camera frame",
             {"header": {"seq": 1, "stamp": {"secs": 1700000000, "nsecs": 0}, "frame_id": names.CAMERA_FRAME_ID},
              "head_yaw": 12.5, "head_pitch": -3.0, "stamp_gap": 0.0, "source": "render"}),
)


def endpoints() -> list[dict[str, Any]]:
    """JSON-ready, with each example as the frame a client sends or receives."""
    return [{**asdict(e), "example_frame": e.example_frame()} for e in ENDPOINTS]
