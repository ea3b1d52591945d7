"""The pure core: parameters, the kinematic model, backlash, G-code words and modal
state, arcs and the reference compensator. Imports nothing from OctoPrint or the other floors."""
