"""Tables and figures for results/ (atomic writes, Markdown twins of every table)."""
