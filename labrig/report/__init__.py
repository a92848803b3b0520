"""The HTML report: gathers the stages' results and figures and renders them with Jinja2."""
