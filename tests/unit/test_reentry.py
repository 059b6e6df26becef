"""Resuming within a layer: where it continues, and the moves back."""

from __future__ import annotations

from hostd.printing.reentry import reentry_moves, resume_line


def test_the_resume_continues_at_the_first_unacknowledged_command_or_goes_back_the_planner():
    assert resume_line(acked=150, replay=0) == 150  # the printer kept its power
    assert resume_line(acked=150, replay=16) == 134  # it reset: its planner's moves again
    assert resume_line(acked=10, replay=16) == 0  # never before the layer's start


def test_moves_back_restore_retraction_position_height_and_feed_without_extruding():
    layer = [";LAYER:3", "G1 E-1.00000 F2100", "G0 F9000 X60.225 Y124.775 Z0.800",
             "G1 E1.00000 F2100", ";TYPE:WALL-OUTER", "G1 F2400 X60.225 Y95.225 E1.10569",
             "G1 X84.786 Y95.225 E0.91901"]
    assert reentry_moves(layer[:3]) == ("G1 E-1.00000 F2100", "G0 F9000 X60.225 Y124.775",
                                        "G0 F600 Z0.800", "G1 F9000")
    assert reentry_moves(layer) == ("G0 F9000 X84.786 Y95.225", "G0 F600 Z0.800", "G1 F2400")
    assert reentry_moves(layer[:2]) == ("G1 E-1.00000 F2100", "G1 F2100")  # not moved yet
    assert reentry_moves([]) == ()
