"""What a sweep's scene run ended as (its verdict), the criteria that stop a run that will not climb, and what each
verdict means (for the sweep's table, its map and its report: cedra.sweep)."""
from __future__ import annotations


STUCK_TIME = 3.0       # s: a run whose body advanced less than STUCK_DX in this long is stopped: it will not climb
STUCK_DX = 0.005
TIPPED = 1.2           # rad: |body pitch| or |body roll| past this is a rover on its back or side: not a climb
HUNG_FN = 5.0          # N: a rover that did not get over is hung up when its chassis carried more than this on mean
VERDICTS = {           # a scene run's verdict -> its meaning (verdict())
    "over": "every wheel center passed the obstacle's end, upright (climbed = 1)",
    "stuck": f"not over: body.x advanced less than {STUCK_DX * 1e3:g} mm in {STUCK_TIME:g} s, or the stop time "
             f"came first (the reason says which)",
    "hung up": f"stuck while the chassis carries load: the mean of chassis.Fn over the last {STUCK_TIME:g} s of the "
               f"run > {HUNG_FN:g} N (only an FMU with the output chassis.Fn can hang up)",
    "tipped": f"body pitch or roll past +-{TIPPED} rad (on its back or side)",
    "failed": "the run did not finish: status other than ok (the FMU refused a step, a timeout, an error); a "
              "failure to simulate, not a failure to climb",
}


def verdict(status: str, climbed: bool, tipped: bool, chassis_fn_mean: float | None) -> str:
    """A scene run's verdict (VERDICTS) from how it ended; chassis_fn_mean is the mean of chassis.Fn over the last
    STUCK_TIME of the run, None when the FMU has no such output."""
    if status != "ok":
        return "failed"
    if climbed:
        return "over"
    if tipped:
        return "tipped"
    if chassis_fn_mean is not None and chassis_fn_mean > HUNG_FN:
        return "hung up"
    return "stuck"
