"""The build engine: the tasks a build runs, the worker processes they run in, where they stage
what they hand on, what the recordings add up to in the manifest, and the sizes that bound each
task's memory (docs/design.md)."""
