"""Files shipped with vecu for users to run by name: scenarios/ and campaigns/ (vecu.shipped)."""
