"""The model in: STL files read, meshes checked and repaired, shells labelled, layers cut
into outlines (lazily, a block at a time, or in a forked process).
"""
