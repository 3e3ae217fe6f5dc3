"""Fakes at the hardware boundary: a NAOqi robot served over real libqi, an evdev
event stream, and the libftdi1 boundary of a Novint Falcon."""
