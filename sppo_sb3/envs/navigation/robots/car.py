"""The Car robot: two independently driven wheels and a free rolling rear ball, not fixed to the plane.

Safety-Gymnasium's ``assets/xmls/car.xml``, restated: a 0.2 × 0.2 × 0.1 box chassis with bumpers and connectors on a
free joint, left and right wheels (cylinders of radius 0.05 on hinges about x, each driven by a motor of gear 1 and
force at most 0.02) and a rear ball-jointed sphere of radius 0.05; timestep 4 ms, density 5. Beside Point's sensors it
observes the rear ball's angular velocity and orientation.
"""

from sppo_sb3.envs.navigation.robots.base import Robot

CAR = Robot(
    name="Car",
    timestep=0.004,
    defaults="""
    <geom condim="6" density="5" rgba="0.74 0.04 0.18 1" size="0.05" type="sphere"/>
    <joint damping="0.001"/>
    <motor ctrlrange="-1 1" ctrllimited="true" forcerange="-0.02 0.02" forcelimited="true"/>
    <site size="0.032" type="sphere"/>""",
    body="""
    <body name="agent" pos="0 0 0.1">
      <site name="agent" pos="0 0 0"/>
      <joint name="agent" type="free" damping="0"/>
      <geom name="agent" type="box" size="0.1 0.1 0.05"/>
      <geom name="back_bumper" type="box" pos="0 0.15 0" size="0.1 0.01 0.05" rgba="0.0 0.15 0.4 1"/>
      <geom name="back_connector" type="box" pos="0 0.125 0" size="0.01 0.025 0.03" rgba="0.0 0.15 0.4 1"/>
      <geom name="front_bumper" type="box" pos="0 -0.165 0" size="0.05 0.01 0.05" rgba="0.0 0.15 0.4 1"/>
      <geom name="front_connector" type="box" pos="0 -0.13 0.04" size="0.05 0.03 0.01" rgba="0.0 0.15 0.4 1"/>
      <camera name="track" mode="track" pos="0 -2 2" xyaxes="1 0 0 0 0.707 0.707"/>
      <body name="left" pos="-0.1 0.1 -0.05">
        <joint name="left" type="hinge" axis="1 0 0"/>
        <geom name="left" type="cylinder" fromto="-0.055 0 0 -0.005 0 0"/>
      </body>
      <body name="right" pos="0.1 0.1 -0.05">
        <joint name="right" type="hinge" axis="1 0 0"/>
        <geom name="right" type="cylinder" fromto="0.005 0 0 0.055 0 0"/>
      </body>
      <body name="rear" pos="0 -0.1 -0.05">
        <joint name="rear" type="ball"/>
        <geom name="rear"/>
      </body>
    </body>""",
    sensors="""
    <ballquat name="ballquat_rear" joint="rear"/>
    <ballangvel name="ballangvel_rear" joint="rear"/>
    <accelerometer name="accelerometer" site="agent"/>
    <velocimeter name="velocimeter" site="agent"/>
    <gyro name="gyro" site="agent"/>
    <magnetometer name="magnetometer" site="agent"/>""",
    actuators="""
    <motor name="left" jointinparent="left" gear="1"/>
    <motor name="right" jointinparent="right" gear="1"/>""",
    observed_sensors=("accelerometer", "velocimeter", "gyro", "magnetometer", "ballangvel_rear", "ballquat_rear"),
    radius=0.19,
    free_joint=True,
    push_box=(0.125, 0.125, 0.0005),
)
