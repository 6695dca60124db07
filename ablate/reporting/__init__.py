"""From tracked runs to a hand-in: results and statistics, figures, the report document, status."""
