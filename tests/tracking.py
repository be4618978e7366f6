"""Where the closed-loop tests in third-party masters score tracking."""

#: Mean |r - l| is taken from here on [s]: after the controller's start-up mode, which lasts 12 s from
#: the start, or from the switch when the controller detects a parallel master's delay (at about 5 s).
TRACKING_FROM_S = 20.0
