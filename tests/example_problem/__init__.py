"""A fifth estimation problem built by the recipe of docs/architecture.md ("Recipe: add an
estimation problem"), small enough to read in one sitting; tests/test_problem_template.py keeps
it working."""
