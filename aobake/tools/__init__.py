"""Tools on top of the methods: compare two bakes, sweep settings against a reference,
render previews. They compute numbers, tables and pictures from arrays and timed calls;
reading and writing meshes is the pipeline's job."""
