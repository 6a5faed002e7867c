"""Pipeline stages. Each is a thin module with ``run(params, root) -> outputs`` and ``main()``.

Stage name = ``params.yaml`` section = module name = notebook name.
"""
