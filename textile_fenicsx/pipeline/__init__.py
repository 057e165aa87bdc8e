"""The stages in order (stages.run: model -> plates -> contact solve -> correction), what a run is
asked and what it produced (runs: Settings, Run), compaction and spreading of the relaxed fabric,
and the run's output folder (outputs).
"""
