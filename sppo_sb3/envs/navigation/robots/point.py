"""The Point robot: a sphere with a heading, pushed along its heading and turned about the vertical.

Safety-Gymnasium's ``assets/xmls/point.xml``, restated: a 0.1-radius sphere (friction 1, 0.01, 0.01) with a 0.05 box
marking its front, on two slide joints (x, y; damping 0.01) and a hinge about z (damping 0.005); a motor along its
heading (gear 0.3, force at most 0.05) and a velocity servo on the hinge (gear 0.3); timestep 2 ms, density 1.
"""

from sppo_sb3.envs.navigation.robots.base import Robot

POINT = Robot(
    name="Point",
    timestep=0.002,
    defaults="""
    <geom condim="6" density="1" rgba="0.74 0.04 0.18 1"/>
    <joint damping="0.001"/>
    <motor ctrlrange="-1 1" ctrllimited="true" forcerange="-0.05 0.05" forcelimited="true"/>
    <velocity ctrlrange="-1 1" ctrllimited="true" forcerange="-0.05 0.05" forcelimited="true"/>
    <site size="0.032" type="sphere"/>""",
    body="""
    <body name="agent" pos="0 0 0.1">
      <joint name="x" type="slide" axis="1 0 0" damping="0.01"/>
      <joint name="y" type="slide" axis="0 1 0" damping="0.01"/>
      <joint name="z" type="hinge" axis="0 0 1" damping="0.005"/>
      <geom name="agent" type="sphere" size="0.1" friction="1 0.01 0.01"/>
      <geom name="pointarrow" type="box" pos="0.1 0 0" size="0.05 0.05 0.05" rgba="0.0 0.15 0.4 1"/>
      <site name="agent" rgba="1 0 0 0.1"/>
      <camera name="track" mode="track" pos="0 -2 2" xyaxes="1 0 0 0 0.707 0.707"/>
    </body>""",
    sensors="""
    <accelerometer name="accelerometer" site="agent"/>
    <velocimeter name="velocimeter" site="agent"/>
    <gyro name="gyro" site="agent"/>
    <magnetometer name="magnetometer" site="agent"/>""",
    actuators="""
    <motor name="x" site="agent" gear="0.3 0 0 0 0 0"/>
    <velocity name="z" jointinparent="z" gear="0.3"/>""",
    observed_sensors=("accelerometer", "velocimeter", "gyro", "magnetometer"),
    radius=0.16,
    free_joint=False,
)
