"""ROS recordings (a ROS 1 ``.bag``, a rosbag2 folder, a bare ``.mcap`` of any profile) read as
RGB-D sequences and written back: the ``slimseg[ros]`` extra's part of :mod:`slimseg.data`
(docs/bags.md). :mod:`~slimseg.data.bags.reader` opens a recording,
:mod:`~slimseg.data.bags.sequence` reads one as a :class:`~slimseg.data.frame_source.FrameSource`,
:mod:`~slimseg.data.bags.writer` and :mod:`~slimseg.data.bags.foxglove_writer` write one,
:mod:`~slimseg.data.bags.to_tum` and :mod:`~slimseg.data.bags.from_tum` convert to and from a
TUM folder."""
