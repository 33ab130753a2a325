"""Reading logs after the fact: metrics (``cosim inspect``), figures, the HTML report and exports."""
