"""What a run reports: the figures and the text of what the job computed (the summary, its
facts, a design's curves: :mod:`orchestration.studies` computes them, the report calls no
study), and the progress shown meanwhile."""
