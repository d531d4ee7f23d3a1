"""Every topic and service name the server uses, defined once; the modules import them from here.

interface.py (what clients see) spells its endpoints with these constants, and tests/test_names.py checks that no
server module spells one of these names as a literal. Wire names are a contract: change one here only with the
clients that use it.
"""

from __future__ import annotations

import json
from types import MappingProxyType

# ---- the robot (LuxAI's QTrobot interface) ----------------------------------------------------------------------
JOINT_STATE_TOPIC = "/qt_robot/joints/state"
HEAD_COMMAND_TOPIC = "/qt_robot/head_position/command"
RIGHT_ARM_COMMAND_TOPIC = "/qt_robot/right_arm_position/command"
LEFT_ARM_COMMAND_TOPIC = "/qt_robot/left_arm_position/command"
# The part -> command-topic map (the robot's parts as robot_models names them).
PART_COMMAND_TOPICS = MappingProxyType({"head": HEAD_COMMAND_TOPIC, "right_arm": RIGHT_ARM_COMMAND_TOPIC,
                                        "left_arm": LEFT_ARM_COMMAND_TOPIC})
COMMAND_TOPIC_PARTS = MappingProxyType({topic: part for part, topic in PART_COMMAND_TOPICS.items()})
CAMERA_TOPIC = "/camera/color/image_raw/compressed"
CAMERA_FRAME_ID = "camera_color_optical_frame"
# Each camera frame's head pose when it was taken (vr_teleop_msgs/CapturePose; its header is the frame's own):
# published with every frame of CAMERA_TOPIC, just before it, while someone watches that topic.
CAPTURE_POSE_TOPIC = "/vr_teleop/camera/capture_pose"
MOTOR_STATES_TOPIC = "/qt_robot/motors/states"  # the real robot's, read by the ros backend
# The real robot's microphone as LuxAI's qt_respeaker_app publishes it (audio_common_msgs/AudioData, mono S16LE at
# 16 kHz: channel 0 is the ReSpeaker's processed, beamformed channel), read by the ros backend for the WebRTC audio.
ROBOT_MICROPHONE_TOPIC = "/qt_respeaker_app/channel0"
# The operator's voice for a real robot's speaker (audio_common_msgs/AudioData, mono S16LE at 16 kHz), published by the
# ros backend on the robot's rosbridge; audio_common's audio_play on the robot plays it (README, "Media").
ROBOT_SPEAKER_TOPIC = "/vr_teleop/robot/speaker"
EMOTION_SHOW_SERVICE = "/qt_robot/emotion/show"
SPEECH_SAY_SERVICE = "/qt_robot/speech/say"
SPEECH_STOP_SERVICE = "/qt_robot/speech/stop"
SPEECH_CONFIG_SERVICE = "/qt_robot/speech/config"
GESTURE_PLAY_SERVICE = "/qt_robot/gesture/play"
GESTURE_STOP_SERVICE = "/qt_robot/gesture/stop"
GESTURE_LIST_SERVICE = "/qt_robot/gesture/list"
GESTURE_RECORD_SERVICE = "/qt_robot/gesture/record"
GESTURE_SAVE_SERVICE = "/qt_robot/gesture/save"
MOTORS_HOME_SERVICE = "/qt_robot/motors/home"
MOTORS_CONTROL_MODE_SERVICE = "/qt_robot/motors/setControlMode"

# ---- the headset's streams (explicit control) -------------------------------------------------------------------
HEAD_POSE_TOPIC = "/vr/head/pose"
CONTROLLER_POSE_TOPICS = MappingProxyType({"left": "/vr/left_controller/pose", "right": "/vr/right_controller/pose"})
JOY_TOPICS = MappingProxyType({"left": "/vr/left_controller/joy", "right": "/vr/right_controller/joy"})

# ---- the server's own ---------------------------------------------------------------------------------------------
EVENT_TOPIC = "/vr_teleop/events"
TELEOP_STATE_TOPIC = "/vr_teleop/teleop_state"
CLAMP_TOPIC = "/vr_teleop/clamps"
DESCRIPTION_TOPIC = "/vr_teleop/robot_description"
ENGAGE_SERVICE = "/vr_teleop/control/engage"
CALIBRATE_SERVICE = "/vr_teleop/control/calibrate"
RECENTER_SERVICE = "/vr_teleop/control/recenter"
HEAD_SERVICE = "/vr_teleop/control/head"
ARMS_SERVICE = "/vr_teleop/control/arms"
ESTOP_SERVICE = "/vr_teleop/control/estop"
MENUS_TOPIC = "/vr_teleop/menus"
MENU_SELECT_SERVICE = "/vr_teleop/menu/select"
MENU_SELECTION_TOPIC = "/vr_teleop/menu/selection"
HARDWARE_STATUS_TOPIC = "/vr_teleop/status/hardware"
MOTORS_STATUS_TOPIC = "/vr_teleop/status/motors"
ROBOT_HARDWARE_STATUS_TOPIC = "/vr_teleop/status/robot_hardware"
DIALOG_STATUS_TOPIC = "/vr_teleop/status/dialog"
DIALOG_UPDATE_TOPIC = "/vr_teleop/dialog/update"
MOTIVATION_STATUS_TOPIC = "/vr_teleop/status/motivation"
MOTIVATION_SET_SERVICE = "/vr_teleop/motivation/set"
MOTIVATION_INCREMENT_SERVICE = "/vr_teleop/motivation/increment"
MOTIVATION_RESET_SERVICE = "/vr_teleop/motivation/reset"
ROBOT_AUDIO_TOPIC = "/vr_teleop/audio/robot"
ROBOT_AUDIO_INFO_TOPIC = "/vr_teleop/audio/robot/info"
OPERATOR_AUDIO_TOPIC = "/vr_teleop/audio/operator"
OPERATOR_AUDIO_INFO_TOPIC = "/vr_teleop/audio/operator/info"
FACES_TOPIC = "/perception/faces"
# serve --blur-faces (vr_teleop_server/features/face_blur.py): the head camera with every detected face blurred
# (sensor_msgs/CompressedImage; what a spectator's subscription to CAMERA_TOPIC is served from), and in recordings,
# beside each kept camera frame, what was blurred in it (vr_teleop_msgs/FaceBlur)
CAMERA_BLURRED_TOPIC = "/vr_teleop/camera/blurred/compressed"
FACE_BLUR_TOPIC = "/vr_teleop/face_blur"
WHOAMI_SERVICE = "/vr_teleop/whoami"
# The robot's language (features/speech.py's LANGUAGES: en, de, fr, lb): set with the service
# (vr_teleop_msgs/SetLanguage), the one in force on the latched topic (std_msgs/String holding its code)
SPEECH_LANGUAGE_SERVICE = "/vr_teleop/speech/set_language"
SPEECH_LANGUAGE_TOPIC = "/vr_teleop/speech/language"
# Voices from home (features/clips.py, `serve --clips DIR`): the library on a latched topic (vr_teleop_msgs/Clips),
# a clip added (supervisor only; vr_teleop_msgs/AddClip), removed (supervisor only) or played through the robot
CLIPS_TOPIC = "/vr_teleop/clips"
CLIP_ADD_SERVICE = "/vr_teleop/clips/add"
CLIP_REMOVE_SERVICE = "/vr_teleop/clips/remove"
CLIP_PLAY_SERVICE = "/vr_teleop/clips/play"
# The caller's own voice (the operator voice road) recorded as a clip: the first call starts, the next stops and keeps
# it (std_srvs/Trigger); while it records, that voice is not played on the robot
CLIP_RECORD_SERVICE = "/vr_teleop/clips/record"

# ---- the robot avatar (ROS#'s URDF importer and JointStatePatcher) ------------------------------------------------
URDF_JOINT_STATES_TOPIC = "/joint_states"  # sensor_msgs/JointState, radians, URDF joint names
ROBOT_DESCRIPTION_PARAM = "robot_description"  # a rosapi parameter (the URDF), not a topic
FILE_SERVER_SERVICE = "/file_server/get_file"
# rosapi's clock (core/rosapi.py serves /rosapi/*): the page's clock sync, and the clients' round trip (sync())
ROSAPI_GET_TIME_SERVICE = "/rosapi/get_time"

# ---- the study framework ------------------------------------------------------------------------------------------
STUDY_LABELS_TOPIC = "/study/labels"
STUDY_LABEL_START_SERVICE = "/study/label/start"
STUDY_LABEL_STOP_SERVICE = "/study/label/stop"
STUDY_LABEL_ADD_SERVICE = "/study/label/add"
STUDY_STATE_UPDATES_TOPIC = "/study/state_updates"
STUDY_INTERVENTIONS_TOPIC = "/study/interventions"
STUDY_TRIAL_TOPIC = "/study/trial"
STUDY_METRICS_TOPIC = "/study/metrics"
# the live study (`serve --study FILE --study-dir DIR`): the experimenter's services (supervisor), the session,
# and the participant's own (the participant role: their token from /study/participants/add)
STUDY_SESSION_TOPIC = "/study/session"
STUDY_PARTICIPANT_ADD_SERVICE = "/study/participants/add"
STUDY_TRIAL_START_SERVICE = "/study/trial/start"
STUDY_TRIAL_END_SERVICE = "/study/trial/end"
STUDY_NOTE_SERVICE = "/study/note"
STUDY_QUESTIONNAIRE_SUBMIT_SERVICE = "/study/questionnaire/submit"
STUDY_QUESTIONNAIRE_DUE_SERVICE = "/study/questionnaire/due"
DECISION_TELEOP_SERVICE = "/decision/teleop"
DECISION_PREEMPT_SERVICE = "/decision/preempt"
DECISION_OVERRIDE_SERVICE = "/decision/override"
PERCEPTION_QUERY_SERVICE = "/perception/query"

# ---- recordings' own channels (not on the bus) --------------------------------------------------------------------
RECORDING_IN_CHANNEL = "/rosbridge/in"
RECORDING_OUT_CHANNEL = "/rosbridge/out"
RECORDING_CONNECTIONS_CHANNEL = "/rosbridge/connections"


def javascript_module() -> str:
    """This module's names as an ES module for the pages (vr_teleop_server/web/names.js; `vr-teleop schema
    --names-js` writes it, tests/test_names.py checks it is current): every string constant, and each map as a
    frozen object."""
    lines = ["// Generated from client_protocol/names.py by `vr-teleop schema --names-js`: do not edit.",
             "// Every topic and service name the server uses; the pages import them from here."]
    for key, value in globals().items():
        if not key.isupper():
            continue
        if isinstance(value, str):
            lines.append(f"export const {key} = {json.dumps(value)};")
        elif isinstance(value, MappingProxyType):
            lines.append(f"export const {key} = Object.freeze({json.dumps(dict(value))});")
    return "\n".join(lines) + "\n"


def all_names() -> dict[str, str]:
    """Every name above, by its constant's name (names only in a map as NAME[key])."""
    constants = {key: value for key, value in globals().items() if key.isupper()}
    found = {key: value for key, value in constants.items() if isinstance(value, str) and value.startswith("/")}
    spelled = set(found.values())
    for key, value in constants.items():
        if isinstance(value, MappingProxyType) and key != "COMMAND_TOPIC_PARTS":
            found.update({f"{key}[{k!r}]": v for k, v in value.items() if v not in spelled})
    return found

# ---- media: WebRTC beside the rosbridge stream (vr_teleop_server/media) ----
MEDIA_OFFER_SERVICE = "/vr_teleop/media/offer"
CLOCK_SERVICE = "/vr_teleop/clock"
# The ICE servers (STUN/TURN) and fresh TURN credentials a client uses for its peer connection
MEDIA_ICE_SERVERS_SERVICE = "/vr_teleop/media/ice_servers"
TELEMETRY_TOPIC = "/vr_teleop/telemetry"
# The data channel the operator's poses and Joy take beside the media (label; ordered false, maxRetransmits 0)
POSES_CHANNEL = "poses"
# The data channel each WebRTC video frame's capture pose comes on, keyed by the frame's RTP timestamp (label; the
# client opens it before the offer, ordered false, maxRetransmits 0; the server only sends on it)
CAPTURE_POSES_CHANNEL = "capture_poses"

# ---- supervised autonomy (vr_teleop_server/features/autonomy) ----
AUTONOMY_LEVEL_SERVICE = "/vr_teleop/autonomy/level"
AUTONOMY_STATE_TOPIC = "/vr_teleop/autonomy/state"
AUTONOMY_ATTENTION_TOPIC = "/vr_teleop/autonomy/attention"
AUTONOMY_PROPOSALS_TOPIC = "/vr_teleop/autonomy/proposals"
AUTONOMY_DECIDE_SERVICE = "/vr_teleop/autonomy/decide"
AUTONOMY_OUTCOMES_TOPIC = "/vr_teleop/autonomy/outcomes"
# The one name of each person the robot tracks (vr_teleop_msgs/RenamePerson: a track id and the name every view
# shows for it from then on)
PEOPLE_RENAME_SERVICE = "/vr_teleop/people/rename"
# The ROS 1 QTrobot's microphone array as LuxAI's qt_respeaker_app publishes it (latched): voice activity
# (std_msgs/Bool) and the direction of arrival (std_msgs/Int32, the ReSpeaker's own angle in degrees), read by the
# ros backend and turned into the robot's base frame there.
RESPEAKER_SPEAKING_TOPIC = "/qt_respeaker_app/is_speaking"
RESPEAKER_DIRECTION_TOPIC = "/qt_respeaker_app/sound_direction"
# The stand-in's simulated pupils (simulation only)
SIM_BYSTANDERS_TOPIC = "/sim/bystanders"
SIM_BYSTANDERS_SPEAK_SERVICE = "/sim/bystanders/speak"
SIM_BYSTANDERS_LOOK_SERVICE = "/sim/bystanders/look"
