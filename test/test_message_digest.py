"""The content digest the heatmap server recognises repeated requests by."""

import numpy as np
from advocc_ros.ros.conversions import attack_request
from advocc_ros.ros.digest import message_digest


def test_equal_requests_share_a_digest(table_scene):
    first, second = attack_request(table_scene, 3, 'task'), attack_request(table_scene, 3, 'task')
    assert first is not second and message_digest(first) == message_digest(second)


def test_any_changed_field_changes_the_digest(table_scene):
    base = message_digest(attack_request(table_scene, 3, 'task'))

    def changed(edit):
        request = attack_request(table_scene, 3, 'task')
        edit(request)
        return message_digest(request)

    edits = [
        lambda r: setattr(r, 'seed', 1),
        lambda r: setattr(r, 'budget', 4),
        lambda r: setattr(r, 'goal_policy', 'solvable'),
        lambda r: r.start_state.position.__setitem__(
            1, np.nextafter(r.start_state.position[1], np.inf)),
        lambda r: r.goal_region.position_tolerance.__setitem__(0, 0.021),
        lambda r: setattr(r.scene[0], 'id', 'other'),
        lambda r: setattr(r.cloud, 'data', bytes(12)),
        lambda r: setattr(r, 'scene', r.scene[:-1]),
    ]
    digests = [changed(edit) for edit in edits]
    assert base not in digests and len(set(digests)) == len(digests)
