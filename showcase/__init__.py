"""The showcase: the sample library's scenes and materials, the preview stage, the contact sheet and the
artist asset library. Built on the add-on (``addon``) and the headless harness (``render``).

Importing this package does not import ``bpy``; its modules that build scenes do (``contact_sheet`` is
Pillow only).
"""
