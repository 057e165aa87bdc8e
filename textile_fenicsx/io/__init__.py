"""Model files: TexGen's .tg3 read (tg3) and written (tg3_write), our TOML/JSON (config).
"""
