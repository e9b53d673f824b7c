"""What the programs say in words about a Localizer's run, beside its numbers: what the robustness layer saw and a DF
clock offset the bearings point to (the Localizer itself returns values; these are the sentences built on them)."""
from __future__ import annotations

from aoa_localizer.engine.inference.clock_check import ClockHint
from aoa_localizer.engine.inference.noise import sentence as noise_sentence
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.survey.survey_log import survey_sentence


def clock_hint_sentence(loc: Localizer) -> str | None:
    """Words for a DF clock offset the bearings point to (the view's clock_hint), or None."""
    return clock_hint_words(loc.view().clock_hint, loc.config.df_time_offset_s)


def clock_hint_words(hint: ClockHint | None, df_time_offset_s: float) -> str | None:
    """Words for a DF clock offset `hint` under the configured `df_time_offset_s`, or None."""
    if hint is None:
        return None
    return (f"the bearings fit the track far better with the DF stamps shifted by {hint.shift_s:+.2f} s "
            f"(log-likelihood +{hint.gain:.0f}): a receiver delay or clock offset? try df_time_offset_s = "
            f"{df_time_offset_s + hint.shift_s:.2f}")


def robustness_lines(loc: Localizer) -> list[str]:
    """Human lines on what the robustness layer saw: the receiver's noise, alternative hypotheses, events."""
    lines = []
    view = loc.view()
    est = view.estimate
    if est is not None and est.algorithm == "survey" and est.noise:
        lines.append(survey_sentence(est.noise))
    elif loc.config.calibrate_noise:
        line = noise_sentence(dict(view.noise))
        if est is not None and est.transmitters:  # the channel's calibration reads the others' bearings as wild
            line += " (among them the other transmitters' on the frequency: see the count)"
        lines.append(line)
    pooled = view.receiver_noise
    if pooled is not None:
        lines.append(f"the receiver over its channels: {pooled.sentence()}")
    if est is not None and len(est.modes) > 1:
        lines.append("alternative hypotheses: " + "; ".join(
            f"E {e:.1f} N {n:.1f} ({100 * m:.0f} %)" for e, n, m in est.modes))
    hint = clock_hint_words(view.clock_hint, loc.config.df_time_offset_s)
    if hint:
        lines.append(hint)
    events = {k: v for k, v in view.events.items() if k != "alarm_points"}
    if events:
        lines.append("robustness events: " + ", ".join(f"{k} {v}" for k, v in sorted(events.items())))
    return lines
