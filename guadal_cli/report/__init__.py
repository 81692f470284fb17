"""``guadal report``: tables, figures, animations, geo exports and one HTML page from run directories."""
