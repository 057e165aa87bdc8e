"""Model files: TexGen's .tg3 read and written (tg3), our TOML/JSON (config).
"""
