"""Test scenes and slow, obviously correct references, shared by tests/ and bench/.

- :mod:`.scenes`: procedural meshes, several with closed-form AO, and the bench's large scenes;
- :mod:`.hard_cases`: meshes that break AO bakers (contacts, slivers, voxels, bad topology);
- :mod:`.closed_forms`: exact occlusion of disks and polygons;
- :mod:`.naive_rays`: float64 Moller-Trumbore visibility and ray-cast AO in numpy;
- :mod:`.naive_bunnell`: the disk method's sums and passes, one receiver at a time.

Nothing in the package imports this one (tests/test_layers.py checks it).
"""
