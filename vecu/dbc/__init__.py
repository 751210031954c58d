"""DBC files shipped with vecu (installed as package data vecu.dbc)."""
