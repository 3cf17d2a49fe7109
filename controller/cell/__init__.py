"""Cell descriptions shared by the shells: the readers of scenario files (tracker parameters,
segment masters: :mod:`.reading`), of a cell's elements (moving frame, master axis, robot
group, pick program: :mod:`.elements`) and of whole cells (several frames, robots, sensors
and timed MasterFrame changes: :mod:`.scenario`).  Pure: marked YAML sections in, frozen
specs out; the offline simulator and the ``.tracking`` part of bus.yml read cells with
them.
"""
