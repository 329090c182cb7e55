"""What a run reports: the summary, the figures and the text."""
