"""Effect identification: normal-equation algebra, the block bootstrap, the selection policy and the delay.

Libraries only (arrays in, arrays out); ``qr.diagnose`` composes them.
"""
