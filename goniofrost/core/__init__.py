"""The bottom layer: errors, strict config checks, atomic files, the content-hash cache, the MERL grid.

Every package of the project may import this layer; it imports nothing of the project itself.
"""
