"""The ROS message and service types the project knows, in ROS's own `.msg`/`.srv` text format.

Writing them as ROS does keeps one source for everything derived from a type: the pydantic model that validates
it, the defaults ROS fills in, the `rosapi/TypeDef` that `/rosapi/message_details` returns, the JSON Schema the
Unity team codes against, and the ROS 1 wire format that `cbor-raw` subscriptions carry. Type names are written
in the short `pkg/Type` form; `pkg/msg/Type` and `pkg/srv/Type` name the same types.
"""

MESSAGES: dict[str, str] = {
    # std_msgs
    "std_msgs/Header": "uint32 seq\ntime stamp\nstring frame_id",
    "std_msgs/String": "string data",
    "std_msgs/Bool": "bool data",
    "std_msgs/Float64": "float64 data",
    "std_msgs/Float32": "float32 data",
    "std_msgs/Int32": "int32 data",
    "std_msgs/Empty": "",
    "std_msgs/MultiArrayDimension": "string label\nuint32 size\nuint32 stride",
    "std_msgs/MultiArrayLayout": "MultiArrayDimension[] dim\nuint32 data_offset",
    "std_msgs/Float64MultiArray": "MultiArrayLayout layout\nfloat64[] data",
    # geometry_msgs
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/PointStamped": "Header header\nPoint point",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w",
    "geometry_msgs/Pose": "Point position\nQuaternion orientation",
    "geometry_msgs/PoseStamped": "Header header\nPose pose",
    # sensor_msgs
    "sensor_msgs/JointState": "Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort",
    "sensor_msgs/CompressedImage": "Header header\nstring format\nuint8[] data",
    "sensor_msgs/Image": (
        "Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data"
    ),
    "sensor_msgs/Joy": "Header header\nfloat32[] axes\nint32[] buttons",
    # audio
    "audio_common_msgs/AudioData": "uint8[] data",
    "audio_common_msgs/AudioInfo": (
        "uint8 channels\nuint32 sample_rate\nstring sample_format\nuint32 bitrate\nstring coding_format"
    ),
    # the log every ROS system has
    "rosgraph_msgs/Log": (
        "byte DEBUG=1\nbyte INFO=2\nbyte WARN=4\nbyte ERROR=8\nbyte FATAL=16\n"
        "Header header\nbyte level\nstring name\nstring msg\nstring file\nstring function\nuint32 line\n"
        "string[] topics"
    ),
    # this server's own events
    "vr_teleop_msgs/Clip": "string name\nfloat64 duration",
    "vr_teleop_msgs/Clips": (
        "# The clip library (`serve --clips DIR`), by name; enabled: whether the server keeps clips; playing: the\n"
        "# clip the robot is playing now (empty: none)\nClip[] clips\nbool enabled\nstring playing"
    ),
    "vr_teleop_msgs/Clamp": (
        "# A joint command that did not apply as sent: clamped to limits, or ignored (motor not ON)\n"
        "Header header\nstring source\nstring[] joints\nfloat64[] requested\nfloat64[] applied\nstring[] ignored"
    ),
    "vr_teleop_msgs/Event": (
        "# Something the server did or noticed that a supervisor, a recording or a study log should know:\n"
        "# engage and release, watchdog, e-stop, menu commands, backend connection, motivation limits.\n"
        "# level is info, warning or danger; detail is a JSON object whose fields each kind defines\n"
        "# (client_protocol/events.py; the JSON Schemas event.<kind>.json; the protocol reference's Events).\n"
        "Header header\nstring source\nstring kind\nstring level\nstring detail"
    ),
    "vr_teleop_msgs/TeleopState": (
        "# Explicit control as the server sees it, on /vr_teleop/teleop_state (30 Hz and on every change).\n"
        "# state: idle (never engaged), active, stalled (head poses stopped: holding), released, disconnected\n"
        "# (the holder's connection dropped: holding), estopped, robot_lost (backend gone: holding).\n"
        "# holder: the session holding control, empty when none. pose_age: seconds since the newest valid head\n"
        "# pose, -1 before any. clamped: joints whose last target hit a limit.\n"
        "Header header\nbool engaged\nstring state\nstring holder\nbool head_following\n"
        "bool left_arm_following\nbool right_arm_following\nstring[] clamped\nstring[] velocity_limited\n"
        "float64 pose_age\nfloat64 left_pose_age\nfloat64 right_pose_age\nbool robot_connected"
    ),
    "vr_teleop_msgs/Menu": (
        "# One radial menu. controller: left, right or any; button: what opens it on the Touch controller\n"
        "string id\nstring label\nstring controller\nstring button\nstring icon"
    ),
    "vr_teleop_msgs/MenuItem": (
        "# One item, flattened: parent is the id of the item whose submenu holds it, or the menu's id at the top.\n"
        "# slot: left, top, right or bottom, or 'list' with position the index in a list. command empty = submenu.\n"
        "# args: the command's arguments as a JSON object.\n"
        "string id\nstring menu\nstring parent\nstring label\nstring slot\nint32 position\nstring icon\n"
        "string command\nstring args"
    ),
    "vr_teleop_msgs/Menus": "# Every menu tree, on the latched /vr_teleop/menus\nHeader header\nMenu[] menus\nMenuItem[] items",
    "vr_teleop_msgs/HardwareStatus": (
        "# The server machine's load; temperature_c is meaningful only where has_temperature\n"
        "Header header\nfloat32 cpu_percent\nfloat32 memory_percent\nfloat32 memory_used_mb\n"
        "bool has_temperature\nfloat32 temperature_c\nfloat32 load_1min"
    ),
    "vr_teleop_msgs/RobotHardwareStatus": (
        "# The robot's own hardware as its backend reports it (Robot.hardware_report). backend: sim, ros or luxai;\n"
        "# source: measured (a real robot) or modelled (the stand-in). A figure is meaningful only where its has_\n"
        "# flag is set; missing names each figure the backend cannot give (motor_temperature, motor_voltage,\n"
        "# battery, cpu, memory, temperature: the robot's own computer) and missing_reason says why, in the same\n"
        "# order: interface (the robot's interface gives no way to read it), no_reading (nothing read yet),\n"
        "# not_modelled (the stand-in does not simulate it)\n"
        "Header header\nstring backend\nstring source\nbool connected\nuint32 motors\n"
        "bool has_motor_temperature\nstring hottest_motor\nfloat32 motor_temperature_c\n"
        "bool has_motor_voltage\nfloat32 motor_voltage_min_v\nuint32 motor_faults\n"
        "bool has_battery\nfloat32 battery_percent\nbool has_cpu\nfloat32 cpu_percent\n"
        "bool has_memory\nfloat32 memory_percent\nbool has_temperature\nfloat32 temperature_c\n"
        "string[] missing\nstring[] missing_reason"
    ),
    "vr_teleop_msgs/MotorsStatus": (
        "# One entry per motor, once each. position_normalized: 0 at the joint's lower limit, 1 at its upper.\n"
        "# mode: on, off or brake. fault: what the motor reports wrong (QTrobot v3: overload_limit, voltage_limit,\n"
        "# temperature_limit, sensor_failure; comma-separated), empty when it reports nothing\n"
        "Header header\nstring[] name\nfloat64[] position\nfloat64[] position_normalized\nfloat32[] temperature\n"
        "float32[] voltage\nstring[] mode\nstring[] fault"
    ),
    "vr_teleop_msgs/DialogState": (
        "# The dialog system's state (the prototype's question:mode:answer:candidates:optionals:chosen line)\n"
        "Header header\nstring question\nstring mode\nstring answer\nstring[] candidates\nstring[] optionals\n"
        "string chosen"
    ),
    "vr_teleop_msgs/Motivation": (
        "# The motivation variables. low/high hold a limit only where has_low/has_high.\n"
        "# level: ok, low or high (past its limit)\n"
        "Header header\nstring[] name\nfloat64[] value\nfloat64[] min\nfloat64[] max\nbool[] has_low\n"
        "float64[] low\nbool[] has_high\nfloat64[] high\nstring[] level"
    ),
    # the HRI study framework (vr_teleop_server/study)
    "vr_teleop_msgs/StateUpdate": (
        "# A robot or human action in a study trial, on /study/state_updates: published when it starts\n"
        "# (finished false) and again when it stops (finished true, same id). Times are seconds since the trial\n"
        "# started. agent: robot or human. source: action (the robot's action module), label (the experimenter's\n"
        "# labels), or the name of whatever else reported it. detail: the primitive and its target, as JSON.\n"
        "Header header\nstring trial\nuint32 id\nstring agent\nstring action\nfloat64 start\nbool finished\n"
        "float64 stop\nbool succeeded\nstring source\nstring detail"
    ),
    "vr_teleop_msgs/Intervention": (
        "# A human stepping in where the trial's design says the system acts, on /study/interventions.\n"
        "# kind: override (the experimenter marked an action done or failed), takeover, preempt.\n"
        "# subtask: the robot subtask it affected (empty: none). Times are seconds since the trial started.\n"
        "Header header\nstring trial\nstring kind\nstring subtask\nfloat64 start\nfloat64 stop\nstring note"
    ),
    "vr_teleop_msgs/TrialState": (
        "# A study trial as the runner sees it, on the latched /study/trial (on every change).\n"
        "# state: running, completed, preempted or failed. perception/decision/action: the implementations.\n"
        "# current: the subtask running or awaited, in words. planned_subtasks: robot subtasks in the plan.\n"
        "# awaiting_human: the human action the trial waits for ('' when it waits for none).\n"
        "Header header\nstring study\nstring trial\nstring state\nstring perception\nstring decision\n"
        "string action\nfloat64 elapsed\nstring current\nuint32 planned_subtasks\nstring message\n"
        "string awaiting_human"
    ),
    "vr_teleop_msgs/FluencyMetrics": (
        "# Live fluency metrics of the running trial, on /study/metrics (1 Hz, and once with final true).\n"
        "# Fractions of the elapsed time; defined false while the trial has lasted no time. effectiveness is\n"
        "# -1 until known. detail: the same JSON document `vr-teleop metrics --json` writes.\n"
        "Header header\nstring trial\nbool final\nbool defined\nfloat64 elapsed\nfloat64 h_idle\n"
        "float64 r_idle\nfloat64 c_act\nfloat64 f_del\nfloat64 both_idle\nfloat64 effectiveness\n"
        "uint32 human_actions\nuint32 robot_actions\nuint32 unfinished\nstring detail"
    ),
    "vr_teleop_msgs/Face": (
        "# A face in a camera image: its box in pixels, and the detector's score (higher is surer; the\n"
        "# server's floor is 1.5, real faces score about 2.5-8)\n"
        "int32 x\nint32 y\nint32 width\nint32 height\nfloat32 confidence"
    ),
    "vr_teleop_msgs/Faces": (
        "# Faces found in one head-camera frame, on /perception/faces. detector: what found them.\n"
        "Header header\nuint32 frame_seq\nuint32 image_width\nuint32 image_height\nstring detector\nFace[] faces"
    ),
    "vr_teleop_msgs/FaceBlur": (
        "# What serve --blur-faces blurred in one recorded camera frame, on /vr_teleop/face_blur; header: the\n"
        "# frame's own. detected: a search of this very frame had ended when it was blurred (its boxes are among\n"
        "# faces). detection_seq: the frame the newest search had searched, detection_age seconds before (-1:\n"
        "# none). faces: the held detections' boxes, each blurred grown by margin (of its size) on every side;\n"
        "# whole_frame: no detection recent enough, the frame blurred whole.\n"
        "Header header\nuint32 frame_seq\nbool detected\nuint32 detection_seq\nfloat64 detection_age\n"
        "bool whole_frame\nfloat64 margin\nFace[] faces"
    ),
    # supervised autonomy (vr_teleop_server/features/autonomy)
    "vr_teleop_msgs/AttentionTarget": (
        "# Where the robot's attention is, on /vr_teleop/autonomy/attention (on every change, and 1 Hz).\n"
        "# source: face, voice, both, glance (nobody there: a look around) or empty (no target). id: the person's\n"
        "# track id (the stand-in's pupils by name, a real robot's faces face-1, face-2...) or empty; who: their\n"
        "# name, the one every view shows (the id until /vr_teleop/people/rename gives another). yaw/pitch: the\n"
        "# target's direction in the robot's base frame, degrees (yaw positive to the left). has_face: face holds\n"
        "# the face's box in the camera image, found in the camera frame frame_seq (its header.seq, as\n"
        "# /perception/faces names it; 0 without a face).\n"
        "Header header\nstring source\nstring id\nstring who\nfloat64 yaw\nfloat64 pitch\nbool has_face\n"
        "Face face\nuint32 frame_seq\nfloat64 score"
    ),
    "vr_teleop_msgs/Proposal": (
        "# An action the robot proposes (SPARC), on /vr_teleop/autonomy/proposals. action: a menu item id; label:\n"
        "# that item's words; reason: why, for the teacher; confidence 0..1; timeout: seconds until on_timeout is\n"
        "# done (execute or drop); situation: the situation it was proposed in, as the learner names it.\n"
        "# left: seconds of the time-out left when this message was sent (a page opening onto a pending\n"
        "# proposal counts down from it); 0 once the time-out has come and the proposal waits for the voice,\n"
        "# the face or the parts it needs, which someone else is using.\n"
        "Header header\nstring id\nstring action\nstring label\nstring reason\nfloat64 confidence\n"
        "float64 timeout\nstring on_timeout\nstring situation\nfloat64 left"
    ),
    "vr_teleop_msgs/ProposalOutcome": (
        "# How a proposal ended, or an action the teacher took herself, on /vr_teleop/autonomy/outcomes.\n"
        "# outcome: accepted, rejected, forbidden, timed_out_executed, superseded, dropped, or\n"
        "# teacher_initiated (initiator teacher, an action picked from a menu). decided_by: the operator who\n"
        "# decided, 'timeout', 'autonomy' (the autonomous level executes its own) or 'server'. seconds: from the\n"
        "# proposal to its end.\n"
        "Header header\nstring id\nstring action\nstring outcome\nstring initiator\nstring decided_by\n"
        "float64 seconds\nstring situation"
    ),
    "vr_teleop_msgs/PartOwner": (
        "# Who moves a part now: operator (the holder of control), trial, gesture, client (a LuxAI API client\n"
        "# while it commands and a grace after), autonomy, estop or none. Parts: head, right_arm, left_arm, and\n"
        "# voice (a sentence) and face (an emotion).\n"
        "string part\nstring owner"
    ),
    "vr_teleop_msgs/AutonomyState": (
        "# Autonomy as the server sees it, latched on /vr_teleop/autonomy/state (on every change).\n"
        "# level: teleoperated, supervised or autonomous. running: what autonomy is doing (attention, glance,\n"
        "# an executing proposal's id...). owners: each part's owner.\n"
        "Header header\nstring level\nAttentionTarget attention\nProposal[] pending\nstring[] running\n"
        "PartOwner[] owners"
    ),
    # the stand-in's simulated pupils (simulation only)
    "vr_teleop_msgs/Bystander": (
        "# A simulated pupil: name, position in the robot's base frame (metres), its direction from the robot\n"
        "# (yaw, degrees, positive to the left), where it looks (robot or away) and whether it speaks.\n"
        "string name\ngeometry_msgs/Point position\nfloat64 yaw\nstring looking\nbool speaking"
    ),
    "vr_teleop_msgs/Bystanders": (
        "# The stand-in's pupils, latched on /sim/bystanders (on every change)\nHeader header\nBystander[] bystanders"
    ),
    # ROS 1 actionlib (actionlib_msgs), as roslibpy's ActionClient and SimpleActionServer speak it
    "actionlib_msgs/GoalID": "time stamp\nstring id",
    "actionlib_msgs/GoalStatus": (
        "uint8 PENDING=0\nuint8 ACTIVE=1\nuint8 PREEMPTED=2\nuint8 SUCCEEDED=3\nuint8 ABORTED=4\nuint8 REJECTED=5\n"
        "uint8 PREEMPTING=6\nuint8 RECALLING=7\nuint8 RECALLED=8\nuint8 LOST=9\n"
        "GoalID goal_id\nuint8 status\nstring text"
    ),
    "actionlib_msgs/GoalStatusArray": "Header header\nGoalStatus[] status_list",
    # actionlib's test action (actionlib/TestAction: int32 goal, int32 result, int32 feedback), the type of
    # roslibpy's own actionlib tests, in the message family ROS 1 generates from an .action file
    "actionlib/TestGoal": "int32 goal",
    "actionlib/TestResult": "int32 result",
    "actionlib/TestFeedback": "int32 feedback",
    "actionlib/TestActionGoal": "Header header\nactionlib_msgs/GoalID goal_id\nTestGoal goal",
    "actionlib/TestActionResult": "Header header\nactionlib_msgs/GoalStatus status\nTestResult result",
    "actionlib/TestActionFeedback": "Header header\nactionlib_msgs/GoalStatus status\nTestFeedback feedback",
    "actionlib/TestAction": (
        "TestActionGoal action_goal\nTestActionResult action_result\nTestActionFeedback action_feedback"
    ),
    # media (WebRTC, vr_teleop_server/media)
    "vr_teleop_msgs/ClientTelemetry": (
        "# One client's link as the server sees it. Times in seconds; -1 where not known (yet).\n"
        "# ws_rtt: WebSocket ping to pong. pose_rate/pose_age: the client's head poses (/vr/head/pose) per second\n"
        "# over the last second, and the newest one's age. camera_*: head-camera frames the server handed to this\n"
        "# client (JSON topic and WebRTC together), frames it dropped for it (slow reader or congestion), and the\n"
        "# mean age (render to send) of those sent since the last report. rtc_*: the peer connection (webrtc true):\n"
        "# video codec, RTCP round trip, jitter (s), packets lost (cumulative) and fraction lost (0..1, the newest\n"
        "# receiver report), bits per second sent, the encoder's target bitrate (follows the peer's REMB\n"
        "# estimate), video frames sent. Video RTP timestamps count the server's wall clock at send in\n"
        "# rtp_clock_rate ticks (0 while unknown); frame_rtp_timestamps and frame_render_times give the render time\n"
        "# (wall clock, s since 1970; /vr_teleop/clock puts it on the client's) of each frame sent since the last\n"
        "# report; rtp_timestamp and rtp_render_time are the newest frame's. pose_jitter: how much later than\n"
        "# usual a head pose arrives (95th percentile of the gaps between arrivals over 5 s less their median).\n"
        "# While the client's operator holds control: watchdog_threshold, the adaptive head-pose silence after\n"
        "# which the robot holds, and watchdog_holds, the holds in the last minute (-1 and 0 otherwise).\n"
        "# link_quality: good, degraded or poor, judged while the client's operator holds control once its head\n"
        "# poses arrive ('' otherwise, or while nothing is measured); link_warning: why, in words\n"
        "# (README 'Link quality').\n"
        "# dc_*: the poses data channel (cumulative): messages received, refused (not a publish frame, not an\n"
        "# operator stream topic, control not held, or refused as a WebSocket publish would be), dropped as stale\n"
        "# (stamped before the newest taken on their topic), and the newest refusal's reason.\n"
        "string client\nstring role\nfloat64 ws_rtt\nfloat64 pose_rate\nfloat64 pose_age\n"
        "uint32 camera_frames_sent\nuint32 camera_frames_dropped\nfloat64 camera_frame_age\nbool webrtc\n"
        "string video_codec\nstring rtc_state\nfloat64 rtc_rtt\nfloat64 rtc_jitter\nuint32 rtc_packets_lost\n"
        "float64 rtc_fraction_lost\nfloat64 rtc_bitrate\nfloat64 rtc_target_bitrate\nuint32 rtc_frames_sent\n"
        "uint32 rtp_timestamp\nfloat64 rtp_render_time\nuint32 rtp_clock_rate\nuint32[] frame_rtp_timestamps\n"
        "float64[] frame_render_times\nfloat32 operator_voice_level\nfloat64 pose_jitter\n"
        "float64 watchdog_threshold\nuint32 watchdog_holds\nstring link_quality\nstring link_warning\n"
        "uint32 dc_received\nuint32 dc_refused\nuint32 dc_stale_dropped\nstring dc_last_refusal"
    ),
    "vr_teleop_msgs/CapturePose": (
        "# The robot's head when a camera frame was taken, on /vr_teleop/camera/capture_pose just before the frame.\n"
        "# header: the frame's own (same seq, stamp and frame_id as its sensor_msgs/CompressedImage): match them\n"
        "# by stamp. head_yaw, head_pitch: HeadYaw and HeadPitch in degrees, as /qt_robot/joints/state has them.\n"
        "# source: 'render' (the stand-in: exactly the pose drawn; stamp_gap 0) or 'joint_states' (a real robot:\n"
        "# interpolated between the joint states around the frame's stamp). stamp_gap: seconds from the frame's\n"
        "# stamp to the nearest joint state used (how good the estimate is).\n"
        "Header header\nfloat64 head_yaw\nfloat64 head_pitch\nfloat64 stamp_gap\nstring source"
    ),
    "vr_teleop_msgs/Telemetry": (
        "# Every client's link, on /vr_teleop/telemetry at 2 Hz\nHeader header\nClientTelemetry[] clients"
    ),
    # rosapi's own message
    "rosapi/TypeDef": (
        "string type\nstring[] fieldnames\nstring[] fieldtypes\nint32[] fieldarraylen\nstring[] examples\n"
        "string[] constnames\nstring[] constvalues"
    ),
    "vr_teleop_msgs/IceServer": (
        "# One entry of RTCConfiguration.iceServers: its URLs (stun:, turn:, turns:) and, for TURN, the\n"
        "# credentials (coturn's time-limited ones: username EXPIRY:OPERATOR_KEY, credential base64 HMAC-SHA1).\n"
        "string[] urls\nstring username\nstring credential"
    ),
    "vr_teleop_msgs/StudyParticipant": (
        "# One participant of the live study: pseudonym, group, order of conditions, whether they consented, the\n"
        "# conditions done (ended completed or aborted), the next in their order (empty: none) and what is due.\n"
        "string id\nstring group\nstring[] order\nbool consented\nstring[] done\nstring next\nstring[] due"
    ),
    "vr_teleop_msgs/StudySession": (
        "# The live study (latched /study/session): its participants and the running trial (running_trial 0:\n"
        "# none). balance: a note when the participants do not fill whole balanced sets of orders. actions and\n"
        "# objects: a task study's robot actions and parts, for the Wizard-of-Oz commands (/decision/teleop).\n"
        "string study\nstring kind\nstring design\nstring order\nstring[] conditions\n"
        "StudyParticipant[] participants\nstring[] withdrawn\nstring running_participant\nint32 running_trial\n"
        "string running_condition\nstring running_recording\nstring balance\nstring[] actions\nstring[] objects"
    ),
}

SERVICES: dict[str, str] = {
    "std_srvs/Trigger": "---\nbool success\nstring message",
    "std_srvs/SetBool": "bool data\n---\nbool success\nstring message",
    "std_srvs/Empty": "---",
    # LuxAI's QTrobot API (each service answers `bool status`)
    "qt_robot_interface/emotion_show": "string name\n---\nbool status",
    "qt_robot_interface/speech_say": "string message\n---\nbool status",
    "qt_robot_interface/speech_stop": "---\nbool status",
    "qt_robot_interface/speech_config": "string language\nint16 pitch\nint16 speed\n---\nbool status",
    "qt_gesture_controller/gesture_record": (
        "string[] parts\nbool idleParts\nuint8 wait\nuint8 timeout\n---\nbool status"
    ),
    "qt_gesture_controller/gesture_save": "string name\nstring path\n---\nbool status",
    "qt_gesture_controller/gesture_play": "string name\nfloat32 speed\n---\nbool status",
    "qt_gesture_controller/gesture_list": "---\nstring[] gestures",
    "qt_gesture_controller/gesture_stop": "---\nbool status",
    "qt_motors_controller/home": "string[] parts\n---\nbool status",
    "qt_motors_controller/set_control_mode": "string[] parts\nuint8 mode\n---\nbool status",
    # ROS's file_server package (ROS#'s URDF importer fetches every package:// resource through it)
    "file_server/GetBinaryFile": "string name\n---\nuint8[] value",
    # rospy_tutorials' example service (roslibpy's own service tests use it)
    "rospy_tutorials/AddTwoInts": "int64 a\nint64 b\n---\nint64 sum",
    # this server's own. Every vr_teleop_msgs response carries `bool success` and `string message`: a refusal is a
    # successful call whose response says `success: false` and why (ROS's convention, what ROS# can read);
    # rosbridge's `result: false` is kept for calls that could not run at all. LuxAI's types above keep LuxAI's
    # `bool status` (a real robot answers them so): a refusal there is `status: false`.
    "vr_teleop_msgs/WhoAmI": (
        "# Who the server takes the calling connection to be. connection: this connection's name (as events and\n"
        "# logs name it); role: operator, supervisor or spectator; operator: the operator key the connection\n"
        "# belongs to (every connection of one operator shares it; empty when the role is not operator), the\n"
        "# value /vr_teleop/teleop_state's holder names when this operator holds control; holding: whether it does.\n"
        "---\nbool success\nstring message\nstring connection\nstring role\nstring operator\nbool holding"
    ),
    "vr_teleop_msgs/SetLanguage": (
        "# The robot's language by its code (en, de, fr or lb): its voice, its sentence list and its emotions'\n"
        "# words change together. A refusal (an unknown code, a missing sentence list) says why in message.\n"
        "string language\n---\nbool success\nstring message"
    ),
    "vr_teleop_msgs/AddClip": (
        "# A recorded clip for the library (WAV, Ogg or MP3 bytes; name: letters, digits, - and _). Refused with\n"
        "# the reason when too long, too loud or not decodable. Supervisor only.\n"
        "string name\nuint8[] data\n---\nbool success\nstring message\nfloat64 duration"
    ),
    "vr_teleop_msgs/ClipName": (
        "# One clip of the library by name: played through the robot (answers as it starts; /vr_teleop/clips says\n"
        "# what plays until it has played or was stopped),\n"
        "# or removed from the library (supervisor only).\n"
        "string name\n---\nbool success\nstring message"
    ),
    "vr_teleop_msgs/MenuSelect": (
        "# Run a menu item by id. args: a JSON object merged over the item's own (e.g. {\"text\": \"...\"})\n"
        "string id\nstring args\n---\nbool success\nstring message"
    ),
    "vr_teleop_msgs/MotivationChange": (
        "# name: a motivation variable (reset: empty = all); value: the increment or the new value\n"
        "string name\nfloat64 value\n---\nbool success\nstring message\nfloat64 value"
    ),
    "vr_teleop_msgs/PerceptionQuery": (
        "# The pose of an object's query point (empty: the object's own frame) as a tracking system sees it\n"
        "# (empty tracker: the trial's), in the robot's base frame, metres.\n"
        "string object\nstring tracker\nstring query_point\n---\nbool success\nstring message\n"
        "geometry_msgs/PoseStamped pose\nfloat64 age"
    ),
    "vr_teleop_msgs/DecisionCommand": (
        "# Wizard of Oz: run the study's named robot action on a named object (\"pick\" on \"side_left\").\n"
        "string object\nstring action\n---\nbool success\nstring message"
    ),
    "vr_teleop_msgs/DecisionOverride": (
        "# The experimenter ends the running (or awaited) robot action: succeeded or failed, and the plan moves on.\n"
        "bool succeeded\nstring note\n---\nbool success\nstring message"
    ),
    "vr_teleop_msgs/LabelAction": (
        "# The experimenter's label for a human action: start it now, or stop it now (empty action: the newest).\n"
        "string action\n---\nbool success\nstring message\nfloat64 time"
    ),
    "vr_teleop_msgs/AddLabel": (
        "# A whole action the plan did not foresee, seconds since the trial started (stop < 0: still running).\n"
        "string agent\nstring action\nfloat64 start\nfloat64 stop\n---\nbool success\nstring message"
    ),
    "vr_teleop_msgs/SetAutonomy": (
        "# The autonomy level: teleoperated, supervised or autonomous (operators and supervisors).\n"
        "string level\n---\nbool success\nstring message"
    ),
    "vr_teleop_msgs/DecideProposal": (
        "# The teacher's decision on a pending proposal: accept, reject, or forbid (never in this situation).\n"
        "string id\nstring decision\n---\nbool success\nstring message"
    ),
    "vr_teleop_msgs/BystanderSpeak": (
        "# A simulated pupil says text (espeak-ng, into the robot's microphone). Simulation only.\n"
        "string who\nstring text\n---\nbool success\nstring message"
    ),
    "vr_teleop_msgs/RenamePerson": (
        "# Names a tracked person: id is their track id (AttentionTarget's id), name what every view shows for\n"
        "# them from then on (1-40 characters; empty gives the track id back). Operators and supervisors.\n"
        "string id\nstring name\n---\nbool success\nstring message"
    ),
    "vr_teleop_msgs/BystanderLook": (
        "# A simulated pupil looks at: robot or away. Simulation only.\n"
        "string who\nstring at\n---\nbool success\nstring message"
    ),
    # rosapi, as client libraries (roslibpy, roslibjs, ROS#) call it
    "rosapi/Topics": "---\nstring[] topics\nstring[] types",
    "rosapi/TopicType": "string topic\n---\nstring type",
    "rosapi/TopicsForType": "string type\n---\nstring[] topics",
    "rosapi/Services": "---\nstring[] services",
    "rosapi/ServiceType": "string service\n---\nstring type",
    "rosapi/ServicesForType": "string type\n---\nstring[] services",
    "rosapi/Nodes": "---\nstring[] nodes",
    "rosapi/NodeDetails": "string node\n---\nstring[] subscribing\nstring[] publishing\nstring[] services",
    "rosapi/GetTime": "---\ntime time",
    "rosapi/MessageDetails": "string type\n---\nTypeDef[] typedefs",
    "rosapi/ServiceRequestDetails": "string type\n---\nTypeDef[] typedefs",
    "rosapi/ServiceResponseDetails": "string type\n---\nTypeDef[] typedefs",
    "rosapi/Publishers": "string topic\n---\nstring[] publishers",
    "rosapi/Subscribers": "string topic\n---\nstring[] subscribers",
    "rosapi/GetParam": "string name\nstring default\n---\nstring value",
    "rosapi/SetParam": "string name\nstring value\n---",
    "rosapi/HasParam": "string name\n---\nbool exists",
    "rosapi/DeleteParam": "string name\n---",
    "rosapi/GetParamNames": "---\nstring[] names",
    "rosapi/GetActionServers": "---\nstring[] action_servers",
    # media (WebRTC, vr_teleop_server/media)
    "vr_teleop_msgs/MediaOffer": (
        "# A WebRTC offer from this connection's client (type offer), answered with the server's answer. The\n"
        "# peer connection lives as long as the WebSocket. A refusal answers success false with the reason in\n"
        "# message (sdp and type then empty).\n"
        "string sdp\nstring type\n---\nbool success\nstring message\nstring sdp\nstring type"
    ),
    "vr_teleop_msgs/IceServers": (
        "# The ICE servers this connection's peer connection should use, with TURN credentials made for its\n"
        "# operator, valid until expires (s since 1970; 0 when there is no TURN). Ask again for each new peer\n"
        "# connection. A refusal answers success false with the reason in message (ice_servers then empty).\n"
        "---\nbool success\nstring message\nIceServer[] ice_servers\nfloat64 expires"
    ),
    "vr_teleop_msgs/AddParticipant": (
        "# Enrol a participant (supervisor): a pseudonym (P01 ...) and their order of conditions. consent: given\n"
        "# now, on consent_form (the study file's version). token: their participant page's token.\n"
        "bool consent\nstring consent_form\nstring group\n---\nbool success\nstring message\nstring participant\n"
        "string[] order\nstring token"
    ),
    "vr_teleop_msgs/StartTrial": (
        "# Start a participant's trial (supervisor): condition empty is the next in their order; another one is a\n"
        "# deviation and needs a reason, which is logged. trial: the participant's trial number.\n"
        "string participant\nstring condition\nstring reason\n---\nbool success\nstring message\nint32 trial"
    ),
    "vr_teleop_msgs/EndTrial": (
        "# End the running trial (supervisor): outcome completed or aborted, and an optional note.\n"
        "string outcome\nstring note\n---\nbool success\nstring message"
    ),
    "vr_teleop_msgs/StudyNote": (
        "# A note for the study's event log (supervisor), tied to the running trial if there is one.\n"
        "string text\n---\nbool success\nstring message"
    ),
    "vr_teleop_msgs/SubmitQuestionnaire": (
        "# A participant's answers (the participant role, for themselves): answers_json is a JSON object from\n"
        "# item ids (the sheet's columns: SUS's Q1 to Q10) to answers, or \"prefer_not_to_answer\". condition:\n"
        "# the one it follows (empty before the first or after the last).\n"
        "string questionnaire\nstring condition\nstring answers_json\n---\nbool success\nstring message"
    ),
    "vr_teleop_msgs/QuestionnairesDue": (
        "# What the calling participant should fill in now (the participant role): due_json, a JSON list of\n"
        "# {questionnaire, condition, phase, title, scale, items}; progress: questionnaires given so far.\n"
        "---\nbool success\nstring message\nstring participant\nstring due_json\nint32 answered"
    ),
    "vr_teleop_msgs/Clock": (
        "# NTP-style clock exchange: the client's send time in (any clock, echoed), the server's wall-clock\n"
        "# receive and send times out (s since 1970). offset = ((server_receive - client_send) +\n"
        "# (server_send - client_receive)) / 2, on the client's own clock at client_receive.\n"
        "float64 client_send\n---\nbool success\nstring message\nfloat64 client_send\nfloat64 server_receive\nfloat64 server_send"
    ),
}
