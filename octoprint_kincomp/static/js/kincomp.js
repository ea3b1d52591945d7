$(function () {
    function KinCompViewModel(parameters) {
        var self = this;
    }
    OCTOPRINT_VIEWMODELS.push({construct: KinCompViewModel, dependencies: [], elements: []});
});
