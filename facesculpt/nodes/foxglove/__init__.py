"""The Foxglove room: the graph live in Foxglove, and recordings exported for it.

* ``foxglove`` (:mod:`.node`): a Foxglove WebSocket server (``foxglove-sdk``) showing the
  running graph and taking ``input/events`` from Foxglove's publish panel;
* :mod:`.bridge`: facesculpt messages logged on Foxglove channels (live, or into an MCAP file
  for ``facesculpt bag export --foxglove``);
* :mod:`.convert`: the conversions themselves, arrays in and Foxglove messages out.
"""
