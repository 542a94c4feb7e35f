"""The FMUs with other tools: SSP archives, libcosim, the closed-loop container FMU, cross-check artefacts."""
