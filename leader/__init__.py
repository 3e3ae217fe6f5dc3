"""The operator's side.

Leader devices (simulated Falcon, Falcon, joystick), operator models, the 1 kHz haptic
loop with the force law (31), the browser cockpit.
"""
