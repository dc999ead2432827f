"""The application layer: the commands that wire nodes and their algorithms together
(demo, process, bench, setup, model, keys, and the graph's master/run/launch/topic/bag).
It may import every other layer; nothing imports it but :mod:`facesculpt.cli`.
"""
