"""Attack bags: an MCAP file in rosbag2's format that reads back message for message."""

import importlib

import pytest

from advocc_ros.cli import main as advocc


def _message_class(type_name: str):
    package, _, name = type_name.split('/')
    return getattr(importlib.import_module(f'{package}.msg'), name)


def read_bag(path):
    """(topic, schema, channel, message bytes) of every message, in log-time order."""
    from mcap.reader import make_reader

    with open(path, 'rb') as stream:
        reader = make_reader(stream)
        header = reader.get_header()
        return header, [(channel.topic, schema, channel, message)
                        for schema, channel, message in reader.iter_messages(log_time_order=True)]


def check_round_trip(path, expected):
    """Every message of the bag deserializes (rclpy) into the expected one, in order, and its
    schema text parses (mcap_ros2, as Foxglove does) into the same values."""
    from mcap_ros2.decoder import DecoderFactory
    from rclpy.serialization import deserialize_message

    header, records = read_bag(path)
    assert header.profile == 'ros2'
    assert [r[0] for r in records] == [topic for topic, _ in expected]
    decoders = DecoderFactory()
    for (topic, schema, channel, message), (_, msg) in zip(records, expected):
        assert channel.message_encoding == 'cdr' and schema.encoding == 'ros2msg'
        assert 'durability: 1' in channel.metadata['offered_qos_profiles']
        cls = _message_class(schema.name)
        assert isinstance(msg, cls), (topic, schema.name)
        back = deserialize_message(message.data, cls)
        if hasattr(msg, 'markers'):
            # Marker colours are float32: compare them at float32 precision, the rest exactly.
            for got, want in zip(back.markers, msg.markers):
                for channel_name in 'rgba':
                    assert getattr(got.color, channel_name) == pytest.approx(
                        getattr(want.color, channel_name), abs=1e-7)
                    setattr(got.color, channel_name, getattr(want.color, channel_name))
        assert back == msg, topic
        decoded = decoders.decoder_for('cdr', schema)(message.data)
        if hasattr(msg, 'markers'):  # a MarkerArray has no header of its own
            decoded, msg = decoded.markers[-1], msg.markers[-1]
        assert decoded.header.frame_id == msg.header.frame_id == 'panda_link0'
        stamp = msg.header.stamp
        assert message.log_time == stamp.sec * 10**9 + stamp.nanosec
    return records


@pytest.fixture(scope='module')
def small_heatmap(table_scene):
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap

    return build_heatmap(table_scene, HeatmapConfig(samples=800), seed=0, workers=1)


def test_attack_bag_round_trip(tmp_path, table_scene, small_heatmap):
    from advocc_ros.model.scene import make_box
    from advocc_ros.ros.bag import attack_messages, write_bag

    boxes = [make_box('adv_0', (0.5, 0.0, 0.5), (0.05,) * 3),
             make_box('adv_1', (0.3, 0.2, 0.6), (0.05,) * 3)]
    messages = attack_messages(table_scene, boxes, small_heatmap)
    write_bag(tmp_path / 'attack.mcap', messages, stamp_ns=1_700_000_000_000_000_000)
    records = check_round_trip(tmp_path / 'attack.mcap', messages)
    topics = [r[0] for r in records]
    assert topics == ['/advocc/scene', '/advocc/goal_region', '/advocc/collision_object',
                      '/advocc/collision_object', '/attacker/markers', '/heatmap_server/heatmap']
    boxes_back = [m for t, _, _, m in records if t == '/advocc/collision_object']
    from advocc_msgs.msg import CollisionObject
    from rclpy.serialization import deserialize_message
    first = deserialize_message(boxes_back[0].data, CollisionObject)
    assert first.id == 'adv_0' and list(first.primitives[0].dimensions) == [0.05] * 3
    assert first.primitive_poses[0].position.z == 0.5
    with pytest.raises(ValueError, match='must end in .mcap'):
        write_bag(tmp_path / 'attack.bag', messages)


def test_attack_command_writes_a_bag(tmp_path, table_scene, small_heatmap):
    from advocc_ros.heatmap import save_heatmap

    save_heatmap(small_heatmap, tmp_path / 'h.npz')
    bag = tmp_path / 'bags' / 'attack.mcap'
    assert advocc(['attack', '--heatmap', str(tmp_path / 'h.npz'), '--scene', 'table_pick',
                   '--budget', '2', '--method', 'random', '--out', str(tmp_path / 'obs.yaml'),
                   '--bag', str(bag)]) == 0
    from advocc_ros.attack import load_obstacles
    from advocc_ros.ros.bag import attack_messages

    boxes, _ = load_obstacles(tmp_path / 'obs.yaml')
    header, records = read_bag(bag)
    expected = attack_messages(table_scene, boxes, small_heatmap)
    from advocc_ros.ros.bag import stamp_message
    for (_, _, _, message), (_, msg) in zip(records, expected):
        stamp_message(msg, message.log_time)  # the command stamped them with the time of writing
    check_round_trip(bag, expected)
    assert advocc(['attack', '--heatmap', str(tmp_path / 'h.npz'), '--scene', 'table_pick',
                   '--budget', '2', '--method', 'random', '--out', str(tmp_path / 'obs.yaml'),
                   '--bag', str(tmp_path / 'attack.db3')]) == 2
